//! Link and simulator wrappers the runtime puts around devices: a count of the requests sent
//! (transactions per tick for `--stats`), and a simulated device that can be made to stop
//! answering (a lost device in scenario tests) or to answer slowly.

use crate::link::far_end::{ByteDevice, PacketDevice};
use crate::link::line::LineState;
use crate::link::{ByteLink, LinkError, PacketLink, Watch};
use crate::time::clock::SharedClock;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A shared count of requests sent on every link of a rig.
pub type TransactionCounter = Arc<AtomicU64>;

/// A link that counts what it sends.
pub struct Counted<L> {
    inner: L,
    count: TransactionCounter,
}

impl<L> Counted<L> {
    /// Counts the writes (byte links) or sends (packet links) of `inner` in `count`.
    pub fn new(inner: L, count: TransactionCounter) -> Self {
        Self { inner, count }
    }

    fn bump(&self) {
        self.count.fetch_add(1, Ordering::Relaxed);
    }
}

impl<L: ByteLink> ByteLink for Counted<L> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        self.bump();
        self.inner.write_all(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        self.inner.read(buf, timeout)
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        self.inner.set_baud(baud)
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn line(&mut self) -> Option<&mut LineState> {
        self.inner.line()
    }

    fn watch(&self) -> Option<Watch> {
        self.inner.watch()
    }
}

impl<L: PacketLink> PacketLink for Counted<L> {
    fn send(&mut self, packet: &[u8; 8], timeout: Duration) -> Result<(), LinkError> {
        self.bump();
        self.inner.send(packet, timeout)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        self.inner.receive(timeout)
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }
}

/// Whether a simulated device answers, and how long it takes to; shared between the device
/// and the test that plays the field side.
#[derive(Debug, Clone, Default)]
pub struct Presence {
    gone: Arc<AtomicBool>,
    delay_nanos: Arc<AtomicU64>,
}

impl Presence {
    /// A device that answers at once.
    pub fn new() -> Self {
        Self::default()
    }

    /// Makes the device stop answering (cable pulled) or answer again.
    pub fn set_gone(&self, gone: bool) {
        self.gone.store(gone, Ordering::SeqCst);
    }

    /// Whether the device has stopped answering.
    pub fn is_gone(&self) -> bool {
        self.gone.load(Ordering::SeqCst)
    }

    /// Makes the device take `delay` over each request (a slow module, a busy gateway).
    pub fn set_delay(&self, delay: Duration) {
        let nanos = u64::try_from(delay.as_nanos()).unwrap_or(u64::MAX);
        self.delay_nanos.store(nanos, Ordering::SeqCst);
    }

    /// How long the device takes over each request.
    pub fn delay(&self) -> Duration {
        Duration::from_nanos(self.delay_nanos.load(Ordering::SeqCst))
    }
}

/// A simulated device that hears nothing and says nothing while its `Presence` says gone,
/// and takes its `Presence`'s delay (on the clock it is given) over each request.
pub struct Unpluggable<D> {
    inner: D,
    presence: Presence,
    clock: Option<SharedClock>,
}

impl<D> Unpluggable<D> {
    /// `inner`, present until `presence` says otherwise.
    pub fn new(inner: D, presence: Presence) -> Self {
        Self {
            inner,
            presence,
            clock: None,
        }
    }

    /// Takes the presence's delay on `clock`.
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// Whether to answer, after the delay.
    fn answers(&self) -> bool {
        if self.presence.is_gone() {
            return false;
        }
        let delay = self.presence.delay();
        if let (Some(clock), false) = (&self.clock, delay.is_zero()) {
            clock.sleep_until(clock.now().saturating_add(delay));
        }
        true
    }
}

impl<D: ByteDevice> ByteDevice for Unpluggable<D> {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        if self.answers() {
            self.inner.receive(bytes)
        } else {
            Vec::new()
        }
    }

    fn line_idle(&mut self) -> Vec<u8> {
        if self.presence.is_gone() {
            Vec::new()
        } else {
            self.inner.line_idle()
        }
    }
}

impl<D: PacketDevice> PacketDevice for Unpluggable<D> {
    fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
        if self.answers() {
            self.inner.receive(packet)
        } else {
            None
        }
    }
}

/// A link that is closed: put in place of a failed link before opening it again, so the old
/// one is released first (serial ports and USB interfaces are opened exclusively).
pub struct ClosedLink(pub String);

fn closed(what: &str) -> LinkError {
    LinkError::Disconnected {
        what: what.to_string(),
        detail: "closed, being reopened".into(),
    }
}

impl ByteLink for ClosedLink {
    fn write_all(&mut self, _bytes: &[u8]) -> Result<(), LinkError> {
        Err(closed(&self.0))
    }

    fn read(&mut self, _buf: &mut [u8], _timeout: Duration) -> Result<usize, LinkError> {
        Err(closed(&self.0))
    }

    fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
        Ok(())
    }

    fn describe(&self) -> String {
        self.0.clone()
    }
}

impl PacketLink for ClosedLink {
    fn send(&mut self, _packet: &[u8; 8], _timeout: Duration) -> Result<(), LinkError> {
        Err(closed(&self.0))
    }

    fn receive(&mut self, _timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        Err(closed(&self.0))
    }

    fn describe(&self) -> String {
        self.0.clone()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::memory::MemoryPacketLink;

    struct Echo;
    impl PacketDevice for Echo {
        fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
            Some(*packet)
        }
    }

    #[test]
    fn an_unplugged_device_is_silent_and_sends_are_counted() {
        let presence = Presence::new();
        let count = TransactionCounter::default();
        let mut link = Counted::new(
            MemoryPacketLink::new(Unpluggable::new(Echo, presence.clone()), "echo"),
            count.clone(),
        );
        link.send(&[1; 8], Duration::ZERO).unwrap();
        assert_eq!(link.receive(Duration::ZERO).unwrap(), Some([1; 8]));
        presence.set_gone(true);
        link.send(&[2; 8], Duration::ZERO).unwrap();
        assert_eq!(link.receive(Duration::ZERO).unwrap(), None);
        presence.set_gone(false);
        link.send(&[3; 8], Duration::ZERO).unwrap();
        assert_eq!(link.receive(Duration::ZERO).unwrap(), Some([3; 8]));
        assert_eq!(count.load(Ordering::Relaxed), 3);
    }
}
