//! What answers at the far end of an in-memory link: the traits a simulated device implements
//! (`sim` implements them; `memory` carries bytes and packets to them).

use std::sync::{Arc, Mutex};

/// A simulated device at the far end of a byte stream (the TRP-C29U on its serial line).
pub trait ByteDevice: Send {
    /// Takes bytes as they arrive on the line and returns whatever the device answers.
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8>;
    /// Tells the device the line has been silent for longer than a frame gap; returns what it
    /// answers to a request that only the silence could end.
    fn line_idle(&mut self) -> Vec<u8> {
        Vec::new()
    }
}

/// A simulated device that answers fixed 8-byte packets (the TRC1000).
pub trait PacketDevice: Send {
    /// Takes one OUT packet and returns the IN packet it produces, if any.
    fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]>;
}

impl<T: ByteDevice> ByteDevice for Arc<Mutex<T>> {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        crate::sync::lock(self).receive(bytes)
    }

    fn line_idle(&mut self) -> Vec<u8> {
        crate::sync::lock(self).line_idle()
    }
}

impl<T: PacketDevice> PacketDevice for Arc<Mutex<T>> {
    fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
        crate::sync::lock(self).receive(packet)
    }
}
