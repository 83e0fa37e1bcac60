//! The rig's devices by name and index: lookups, whether one answers, and running an
//! operation the script asked for on one (refused while it is lost).

use super::devices::{C29uDevice, Device, DeviceError, TrcDevice};
use super::state::Runtime;
use std::time::Duration;

impl<H: Clone> Runtime<H> {
    /// The index of the device called `name`.
    pub fn device_index(&self, name: &str) -> Option<usize> {
        self.devices.iter().position(|d| d.name() == name)
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

    /// Whether the device at `idx` answers.
    pub fn online(&self, idx: usize) -> bool {
        self.devices.get(idx).is_some_and(|d| d.health().online())
    }

    /// Runs an operation the script asked for on the device at `idx`: refused while it is
    /// lost; a communication failure marks it lost.
    pub fn command<T>(
        &mut self,
        idx: usize,
        op: impl FnOnce(&mut Device) -> Result<T, DeviceError>,
    ) -> Result<T, DeviceError> {
        let now = self.now();
        let Some(d) = self.devices.get_mut(idx) else {
            return Err(DeviceError::Offline {
                device: format!("device #{idx}"),
                ago: Duration::ZERO,
                cause: "no such device".into(),
            });
        };
        if !d.health().online() {
            return Err(d.health().offline_error(d.name(), now));
        }
        let result = op(d);
        if let Err(e) = &result {
            self.note_failure(idx, e);
        }
        result
    }
}
