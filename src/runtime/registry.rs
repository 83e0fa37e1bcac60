//! The rig's devices by name and index: lookups, whether one answers, and running an
//! operation the script asked for on one (refused while it is lost).

use super::devices::{C29uDevice, Device, DeviceError, TrcDevice};
use super::state::Runtime;
use crate::device::cancel::Cancel;
use std::time::Duration;

impl<H: Clone> Runtime<H> {
    /// The index of the device called `name`.
    pub fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.name() == name)
    }

    /// The devices, in name order, to look at.
    pub fn devices(&self) -> &[Device] {
        &self.devices
    }

    /// Takes the modules not under control yet out of the run (a stop during the start): the
    /// end then neither writes them nor waits out their timeouts.
    pub fn take_out_uncontrolled(&mut self) -> Vec<Device> {
        let (untaken, taken): (Vec<Device>, Vec<Device>) = std::mem::take(&mut self.devices)
            .into_iter()
            .partition(|d| matches!(d, Device::C29u(c) if !c.controlled()));
        self.devices = taken;
        untaken
    }

    /// The device names, for messages.
    pub fn device_names(&self) -> String {
        let names: Vec<&str> = self.devices.iter().map(Device::name).collect();
        names.join(", ")
    }

    /// The name of the device at `idx` ("" if there is none), for log lines.
    pub fn device_name(&self, idx: usize) -> String {
        self.devices.get(idx).map_or("", Device::name).to_string()
    }

    /// The TRC1000 at `idx`.
    pub fn trc(&mut self, idx: usize) -> Option<&mut TrcDevice> {
        self.devices.get_mut(idx).and_then(Device::as_trc)
    }

    /// The TRP-C29U at `idx`.
    pub fn c29u(&mut self, idx: usize) -> Option<&mut C29uDevice> {
        self.devices.get_mut(idx).and_then(Device::as_c29u)
    }

    /// Cuts every device's exchanges short once `cancel` is set (the run's stop flag);
    /// `Cancel::never()` lets them run their course (the end's writes).
    pub fn set_cancel(&mut self, cancel: &Cancel) {
        self.cancel = cancel.clone();
        for d in &mut self.devices {
            d.set_cancel(cancel);
        }
    }

    /// Whether the device at `idx` answers.
    pub fn online(&self, idx: usize) -> bool {
        self.devices.get(idx).is_some_and(|d| d.health().online())
    }

    /// Gets ready to talk to the device at `idx`: feeds every watchdog that is due first (a
    /// feed never waits for more than the exchange under way, `config::feeding`); true if
    /// the device answers, so the exchange is worth making.
    pub fn ready_for_exchange(&mut self, idx: usize) -> bool {
        self.feed_watchdogs();
        self.online(idx)
    }

    /// Runs an operation the script asked for on the device at `idx`: refused while it is
    /// lost; a communication failure marks it lost.
    pub fn command<T>(
        &mut self,
        idx: usize,
        op: impl FnOnce(&mut Device) -> Result<T, DeviceError>,
    ) -> Result<T, DeviceError> {
        let ready = self.ready_for_exchange(idx);
        let now = self.now();
        let Some(d) = self.devices.get_mut(idx) else {
            return Err(DeviceError::Offline {
                device: format!("device #{idx}"),
                ago: Duration::ZERO,
                cause: "no such device".into(),
            });
        };
        if !ready {
            return Err(d.health().offline_error(d.name(), now));
        }
        let result = op(d);
        match &result {
            Ok(_) => self.heard(idx, now),
            Err(e) => self.note_failure(idx, e),
        }
        result
    }
}

#[cfg(test)]
mod tests {
    use crate::runtime::devices::{Device, DeviceError};
    use crate::runtime::testing::{TestRig, IO, PANEL};
    use std::time::Duration;

    #[test]
    fn devices_are_found_by_name_and_index_in_name_order() {
        let mut r = TestRig::started();
        let rt = &mut r.rt;
        assert_eq!(rt.device_index("io"), Some(IO));
        assert_eq!(rt.device_index("panel"), Some(PANEL));
        assert_eq!(rt.device_index("nope"), None);
        assert_eq!(rt.device_names(), "io, panel");
        assert_eq!(rt.device_name(PANEL), "panel");
        assert_eq!(rt.device_name(7), "");
        assert!(rt.c29u(IO).is_some() && rt.trc(IO).is_none());
        assert!(rt.trc(PANEL).is_some() && rt.c29u(PANEL).is_none());
        assert!(rt.c29u(7).is_none() && rt.trc(7).is_none());
        assert!(rt.online(IO) && rt.online(PANEL));
        assert!(!rt.online(7));
    }

    #[test]
    fn a_command_that_gets_no_answer_loses_the_device_and_the_next_is_not_sent() {
        let mut r = TestRig::started();
        r.sim.set_gone("io", true).unwrap();
        let read = |d: &mut Device| match d {
            Device::C29u(c) => Ok(c.driver().read_inputs()?),
            Device::Trc(_) => unreachable!("IO is a TRP-C29U"),
        };
        let e = r.rt.command(IO, read).unwrap_err();
        assert!(e.is_comm_failure(), "{e}");
        assert!(!r.rt.online(IO));
        assert!(r.rt.online(PANEL), "the other device goes on");
        assert!(r.log().contains("io: lost: "), "{}", r.log());
        let before = r.requests();
        r.clock.advance(Duration::from_millis(300));
        let e = r.rt.command(IO, read).unwrap_err();
        assert_eq!(r.requests(), before, "a lost device is not asked");
        let text = e.to_string();
        assert!(text.starts_with("io is offline (lost 300"), "{text}");
        assert!(text.ends_with("the operation was not done"), "{text}");
    }

    #[test]
    fn a_refusal_is_returned_without_losing_the_device() {
        let mut r = TestRig::started();
        let refused = r.rt.command(IO, |_| {
            Err::<(), _>(DeviceError::Offline {
                device: "io".into(),
                ago: Duration::ZERO,
                cause: "refused".into(),
            })
        });
        assert!(refused.is_err());
        assert!(r.rt.online(IO));
    }

    #[test]
    fn a_command_on_no_such_device_says_so() {
        let mut r = TestRig::started();
        let e = r.rt.command(9, |_| Ok(())).unwrap_err();
        assert!(e.to_string().contains("device #9"), "{e}");
        assert!(e.to_string().contains("no such device"), "{e}");
    }
}
