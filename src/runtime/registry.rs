//! The rig's devices as a part of `Runtime`: each by name and index, whether one answers,
//! the count of input accesses and of requests sent; and running an operation the script
//! asked for on one (refused while it is lost).

use super::devices::links::TransactionCounter;
use super::devices::{C29uDevice, Device, DeviceError, TrcDevice};
use super::state::Runtime;
use crate::device::cancel::Cancel;
use std::sync::atomic::Ordering;
use std::time::Duration;

/// The rig's devices, in name order (a part of `Runtime`).
pub struct Devices {
    /// The devices.
    list: Vec<Device>,
    /// Accesses to device inputs so far (fresh readings or not), to tell what reads them.
    input_accesses: u64,
    /// Requests sent on all links.
    transactions: TransactionCounter,
}

impl Devices {
    /// `list` (already opened, in name order), counting requests in `transactions`.
    pub fn new(list: Vec<Device>, transactions: TransactionCounter) -> Self {
        Self {
            list,
            input_accesses: 0,
            transactions,
        }
    }

    /// The devices, in name order.
    pub fn iter(&self) -> std::slice::Iter<'_, Device> {
        self.list.iter()
    }

    /// The devices, to change.
    pub(super) fn iter_mut(&mut self) -> std::slice::IterMut<'_, Device> {
        self.list.iter_mut()
    }

    /// How many there are.
    pub fn len(&self) -> usize {
        self.list.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.list.is_empty()
    }

    /// The device at `idx`.
    pub fn get(&self, idx: usize) -> Option<&Device> {
        self.list.get(idx)
    }

    /// The device at `idx`, to change.
    pub(super) fn get_mut(&mut self, idx: usize) -> Option<&mut Device> {
        self.list.get_mut(idx)
    }

    /// The index of the device called `name`.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.list.iter().position(|d| d.name() == name)
    }

    /// The device names, for messages.
    pub fn names(&self) -> String {
        let names: Vec<&str> = self.list.iter().map(Device::name).collect();
        names.join(", ")
    }

    /// The name of the device at `idx` ("" if there is none), for log lines.
    pub fn name(&self, idx: usize) -> String {
        self.list.get(idx).map_or("", Device::name).to_string()
    }

    /// The TRC1000 at `idx`.
    pub fn trc(&mut self, idx: usize) -> Option<&mut TrcDevice> {
        self.list.get_mut(idx).and_then(Device::as_trc)
    }

    /// The TRP-C29U at `idx`.
    pub fn c29u(&mut self, idx: usize) -> Option<&mut C29uDevice> {
        self.list.get_mut(idx).and_then(Device::as_c29u)
    }

    /// Whether the device at `idx` answers.
    pub fn online(&self, idx: usize) -> bool {
        self.list.get(idx).is_some_and(|d| d.health().online())
    }

    /// Takes the modules not under control yet out of the run (a stop during the start): the
    /// end then neither writes them nor waits out their timeouts.
    pub fn take_out_uncontrolled(&mut self) -> Vec<Device> {
        let (untaken, taken): (Vec<Device>, Vec<Device>) = std::mem::take(&mut self.list)
            .into_iter()
            .partition(|d| matches!(d, Device::C29u(c) if !c.controlled()));
        self.list = taken;
        untaken
    }

    /// Counts one access to a device's inputs.
    pub(super) fn note_access(&mut self) {
        self.input_accesses = self.input_accesses.wrapping_add(1);
    }

    /// Accesses to device inputs so far (fresh readings or not), to tell what reads them.
    pub fn input_accesses(&self) -> u64 {
        self.input_accesses
    }

    /// Requests sent so far on all links.
    pub fn transaction_count(&self) -> u64 {
        self.transactions.load(Ordering::Relaxed)
    }

    /// The counter of requests sent on all links, shared with what watches it (the script's
    /// limits read the clock again after each new request: an exchange takes time).
    pub fn transaction_counter(&self) -> &TransactionCounter {
        &self.transactions
    }
}

impl<'a> IntoIterator for &'a Devices {
    type Item = &'a Device;
    type IntoIter = std::slice::Iter<'a, Device>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

impl<H: Clone> Runtime<H> {
    /// Cuts every device's exchanges short once `cancel` is set (the run's stop flag);
    /// `Cancel::never()` lets them run their course (the end's writes).
    pub fn set_cancel(&mut self, cancel: &Cancel) {
        self.safety.set_cancel(cancel);
        for d in self.devices.iter_mut() {
            d.set_cancel(cancel);
        }
    }

    /// Gets ready to talk to the device at `idx`: feeds every watchdog that is due first (a
    /// feed never waits for more than the exchange under way, `config::feeding`); true if
    /// the device answers, so the exchange is worth making.
    pub fn ready_for_exchange(&mut self, idx: usize) -> bool {
        self.feed_watchdogs();
        self.devices.online(idx)
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
        assert_eq!(rt.devices.index("io"), Some(IO));
        assert_eq!(rt.devices.index("panel"), Some(PANEL));
        assert_eq!(rt.devices.index("nope"), None);
        assert_eq!(rt.devices.names(), "io, panel");
        assert_eq!(rt.devices.name(PANEL), "panel");
        assert_eq!(rt.devices.name(7), "");
        assert!(rt.devices.c29u(IO).is_some() && rt.devices.trc(IO).is_none());
        assert!(rt.devices.trc(PANEL).is_some() && rt.devices.c29u(PANEL).is_none());
        assert!(rt.devices.c29u(7).is_none() && rt.devices.trc(7).is_none());
        assert!(rt.devices.online(IO) && rt.devices.online(PANEL));
        assert!(!rt.devices.online(7));
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
        assert!(!r.rt.devices.online(IO));
        assert!(r.rt.devices.online(PANEL), "the other device goes on");
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
        assert!(r.rt.devices.online(IO));
    }

    #[test]
    fn a_command_on_no_such_device_says_so() {
        let mut r = TestRig::started();
        let e = r.rt.command(9, |_| Ok(())).unwrap_err();
        assert!(e.to_string().contains("device #9"), "{e}");
        assert!(e.to_string().contains("no such device"), "{e}");
    }
}
