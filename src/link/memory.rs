//! In-memory links to simulators, for tests and `--sim` runs: the same driver code, no wire.

use super::{ByteLink, LinkError, PacketLink};
use crate::sim::{ByteDevice, PacketDevice};
use crate::time::clock::SharedClock;
use std::collections::VecDeque;
use std::time::Duration;

/// A byte link whose far end is a simulated device; answers are available as soon as a write
/// returns. A read that finds nothing waits out its timeout on the link's clock, if it has one
/// (so virtual time moves as it would on a wire), or returns at once.
pub struct MemoryByteLink<D: ByteDevice> {
    device: D,
    pending: VecDeque<u8>,
    name: String,
    clock: Option<SharedClock>,
}

impl<D: ByteDevice> MemoryByteLink<D> {
    /// A link to `device`, called `name` in messages.
    pub fn new(device: D, name: impl Into<String>) -> Self {
        Self {
            device,
            pending: VecDeque::new(),
            name: name.into(),
            clock: None,
        }
    }

    /// Makes empty reads wait out their timeout on `clock`.
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// The simulated device at the far end.
    pub fn device(&mut self) -> &mut D {
        &mut self.device
    }
}

impl<D: ByteDevice> ByteLink for MemoryByteLink<D> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        // A driver writes whole frames, so the frame ends here: the line then falls silent.
        let answer = self.device.receive(bytes);
        self.pending.extend(answer);
        let late = self.device.line_idle();
        self.pending.extend(late);
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        if self.pending.is_empty() {
            wait_out(self.clock.as_ref(), timeout);
        }
        let n = buf.len().min(self.pending.len());
        for (slot, byte) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *slot = byte;
        }
        Ok(n)
    }

    fn discard_input(&mut self) -> Result<(), LinkError> {
        self.pending.clear();
        Ok(())
    }

    fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
        Ok(())
    }

    fn describe(&self) -> String {
        format!("simulated {}", self.name)
    }
}

/// A packet link whose far end is a simulated device; empty reads behave as on `MemoryByteLink`.
pub struct MemoryPacketLink<D: PacketDevice> {
    device: D,
    pending: VecDeque<[u8; 8]>,
    name: String,
    clock: Option<SharedClock>,
}

impl<D: PacketDevice> MemoryPacketLink<D> {
    /// A link to `device`, called `name` in messages.
    pub fn new(device: D, name: impl Into<String>) -> Self {
        Self {
            device,
            pending: VecDeque::new(),
            name: name.into(),
            clock: None,
        }
    }

    /// Makes empty reads wait out their timeout on `clock`.
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// The simulated device at the far end.
    pub fn device(&mut self) -> &mut D {
        &mut self.device
    }
}

impl<D: PacketDevice> PacketLink for MemoryPacketLink<D> {
    fn send(&mut self, packet: &[u8; 8], _timeout: Duration) -> Result<(), LinkError> {
        if let Some(answer) = self.device.receive(packet) {
            self.pending.push_back(answer);
        }
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        if self.pending.is_empty() {
            wait_out(self.clock.as_ref(), timeout);
        }
        Ok(self.pending.pop_front())
    }

    fn describe(&self) -> String {
        format!("simulated {}", self.name)
    }
}

/// Lets `timeout` pass on `clock`, as a wire with nothing on it would.
fn wait_out(clock: Option<&SharedClock>, timeout: Duration) {
    if let Some(clock) = clock {
        clock.sleep_until(clock.now().saturating_add(timeout));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::{Clock, VirtualClock};
    use std::sync::Arc;

    struct Echo;
    impl ByteDevice for Echo {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            bytes.iter().rev().copied().collect()
        }
    }
    impl PacketDevice for Echo {
        fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
            (packet[0] != 0).then_some(*packet)
        }
    }

    #[test]
    fn byte_link_returns_answers_in_pieces_and_discards_stale_input() {
        let mut link = MemoryByteLink::new(Echo, "echo");
        link.write_all(b"abc").unwrap();
        let mut buf = [0u8; 2];
        assert_eq!(link.read(&mut buf, Duration::ZERO).unwrap(), 2);
        assert_eq!(&buf, b"cb");
        assert_eq!(link.read(&mut buf, Duration::ZERO).unwrap(), 1);
        assert_eq!(buf[0], b'a');
        assert_eq!(link.read(&mut buf, Duration::ZERO).unwrap(), 0);
        link.write_all(b"xyz").unwrap();
        link.discard_input().unwrap();
        assert_eq!(link.read(&mut buf, Duration::ZERO).unwrap(), 0);
    }

    #[test]
    fn empty_reads_wait_out_their_timeout_on_the_clock() {
        let clock = VirtualClock::at_epoch();
        let mut link = MemoryByteLink::new(Echo, "echo").with_clock(Arc::new(clock.clone()));
        let mut buf = [0u8; 4];
        assert_eq!(link.read(&mut buf, Duration::from_millis(300)).unwrap(), 0);
        assert_eq!(clock.now(), Duration::from_millis(300));
        link.write_all(b"ab").unwrap();
        assert_eq!(link.read(&mut buf, Duration::from_millis(300)).unwrap(), 2);
        assert_eq!(
            clock.now(),
            Duration::from_millis(300),
            "an answer waiting costs no time"
        );
        let mut packets = MemoryPacketLink::new(Echo, "echo").with_clock(Arc::new(clock.clone()));
        assert_eq!(packets.receive(Duration::from_secs(1)).unwrap(), None);
        assert_eq!(clock.now(), Duration::from_millis(1300));
    }

    #[test]
    fn packet_link_queues_only_real_answers() {
        let mut link = MemoryPacketLink::new(Echo, "echo");
        link.send(&[0; 8], Duration::ZERO).unwrap();
        assert_eq!(link.receive(Duration::ZERO).unwrap(), None);
        link.send(&[0x41, 0, 0, 0, 0, 0, 0, 1], Duration::ZERO)
            .unwrap();
        assert_eq!(
            link.receive(Duration::ZERO).unwrap(),
            Some([0x41, 0, 0, 0, 0, 0, 0, 1])
        );
    }
}
