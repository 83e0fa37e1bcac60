//! Simulated TRP-C29U modules on a serial line: each model behind the front end its DIP switch
//! selects, several sharing one line as on an RS-485 bus.

use super::c29u::{C29uModel, Protocol};
use super::c29u_ascii::AsciiFrontEnd;
use super::c29u_modbus::ModbusFrontEnd;
use crate::link::far_end::ByteDevice;
use std::sync::{Arc, Mutex, MutexGuard};

/// A shared handle to a simulated module's model, for the operator side (inputs, resets, state).
pub type SharedModel = Arc<Mutex<C29uModel>>;

/// Locks a shared model; a poisoned lock only means a panicking test thread, the state is whole.
pub fn lock(model: &SharedModel) -> MutexGuard<'_, C29uModel> {
    crate::sync::lock(model)
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
    pub fn new(model: C29uModel) -> Self {
        let front = match model.protocol() {
            Protocol::Ascii => FrontEnd::Ascii(AsciiFrontEnd::new()),
            Protocol::Modbus => FrontEnd::Modbus(ModbusFrontEnd::new()),
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

    fn line_idle(&mut self) -> Vec<u8> {
        match &mut self.front {
            FrontEnd::Ascii(_) => Vec::new(),
            FrontEnd::Modbus(front) => front.end_of_silence(&mut lock(&self.model)),
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

    fn line_idle(&mut self) -> Vec<u8> {
        self.devices
            .iter_mut()
            .flat_map(|d| d.line_idle())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::c29u_modbus::seal;
    use crate::sim::c29u::{Eeprom, ModuleConfig};
    use crate::time::clock::VirtualClock;

    fn module(protocol: Protocol, id: u8) -> SimulatedC29u {
        let eeprom = Eeprom {
            config: ModuleConfig {
                id,
                ..ModuleConfig::factory()
            },
            ..Eeprom::factory()
        };
        SimulatedC29u::new(C29uModel::new(
            protocol,
            Arc::new(VirtualClock::at_epoch()),
            eeprom,
        ))
    }

    #[test]
    fn each_protocol_answers_through_its_front_end_and_shares_its_model() {
        let mut ascii = module(Protocol::Ascii, 1);
        lock(&ascii.model()).set_inputs(0x01);
        assert_eq!(ascii.receive(b"$016\r"), b"!0100FE\r");
        assert!(ascii.line_idle().is_empty());

        let mut modbus = module(Protocol::Modbus, 1);
        lock(&modbus.model()).set_inputs(0x01);
        assert_eq!(
            modbus.receive(&seal(&[1, 1, 0, 0x20, 0, 8])),
            seal(&[1, 1, 1, 0xFE])
        );
        // A vendor request cut short of its reserved byte is answered once the line is silent.
        assert!(modbus.receive(&seal(&[1, 0x46, 0x28])).is_empty());
        assert_eq!(modbus.line_idle(), seal(&[1, 0x46, 0x28, 0]));
    }

    #[test]
    fn only_the_addressed_module_on_a_shared_line_answers() {
        let one = module(Protocol::Modbus, 1);
        let two = module(Protocol::Modbus, 2);
        let (m1, m2) = (one.model(), two.model());
        let mut line = MultiDrop::new();
        line.attach(Box::new(one));
        line.attach(Box::new(two));
        assert_eq!(
            line.receive(&seal(&[2, 0x0F, 0, 0, 0, 8, 1, 0x5A])),
            seal(&[2, 0x0F, 0, 0, 0, 8])
        );
        assert_eq!(lock(&m2).outputs(), 0x5A);
        assert_eq!(lock(&m1).outputs(), 0x00);
        assert!(
            line.receive(&seal(&[3, 1, 0, 0, 0, 8])).is_empty(),
            "nobody has ID 3"
        );
    }
}
