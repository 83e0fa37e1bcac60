//! Simulated TRP-C29U modules on a serial line: each model behind the front end its DIP switch
//! selects, several sharing one line as on an RS-485 bus.

use super::c29u::{C29u, Protocol};
use super::c29u_ascii::AsciiFrontEnd;
use super::c29u_modbus::ModbusFrontEnd;
use super::ByteDevice;
use std::sync::{Arc, Mutex, MutexGuard};

/// A shared handle to a simulated module's model, for the operator side (inputs, resets, state).
pub type SharedModel = Arc<Mutex<C29u>>;

/// Locks a shared model; a poisoned lock only means a panicking test thread, the state is whole.
pub fn lock(model: &SharedModel) -> MutexGuard<'_, C29u> {
    model.lock().unwrap_or_else(|e| e.into_inner())
}

enum FrontEnd {
    Ascii(AsciiFrontEnd),
    Modbus(ModbusFrontEnd),
}

/// One simulated module answering its protocol on a byte stream.
pub struct SimulatedC29u {
    model: SharedModel,
    front: FrontEnd,
}

impl SimulatedC29u {
    /// Puts `model` on a line, speaking the protocol its DIP switch selects.
    pub fn new(model: C29u) -> Self {
        let front = match model.protocol() {
            Protocol::Ascii => FrontEnd::Ascii(AsciiFrontEnd::default()),
            Protocol::Modbus => FrontEnd::Modbus(ModbusFrontEnd::default()),
        };
        Self {
            model: Arc::new(Mutex::new(model)),
            front,
        }
    }

    /// The model, shared with whoever plays the field side.
    pub fn model(&self) -> SharedModel {
        Arc::clone(&self.model)
    }
}

impl ByteDevice for SimulatedC29u {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let mut model = lock(&self.model);
        match &mut self.front {
            FrontEnd::Ascii(front) => front.receive(&mut model, bytes),
            FrontEnd::Modbus(front) => front.receive(&mut model, bytes),
        }
    }

    fn line_idle(&mut self) {
        match &mut self.front {
            FrontEnd::Ascii(_) => {}
            FrontEnd::Modbus(front) => front.line_idle(),
        }
    }
}

/// Several devices on one multi-drop line: every device hears every byte; answers come back
/// in the order the devices were added (only the addressed one answers on a healthy bus).
#[derive(Default)]
pub struct MultiDrop {
    devices: Vec<Box<dyn ByteDevice>>,
}

impl MultiDrop {
    /// An empty line.
    pub fn new() -> Self {
        Self::default()
    }

    /// Connects one more device to the line.
    pub fn attach(&mut self, device: Box<dyn ByteDevice>) {
        self.devices.push(device);
    }
}

impl ByteDevice for MultiDrop {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        self.devices
            .iter_mut()
            .flat_map(|d| d.receive(bytes))
            .collect()
    }

    fn line_idle(&mut self) {
        self.devices.iter_mut().for_each(|d| d.line_idle());
    }
}
