//! In-memory links to simulators, for tests and `--sim` runs: the same driver code, no wire.

use super::line::LineState;
use super::{ByteLink, LinkError, PacketLink};
use crate::link::far_end::{ByteDevice, PacketDevice};
use crate::time::clock::SharedClock;
use std::collections::VecDeque;
use std::time::Duration;

/// How late the answer to the n-th write (from 0) comes, on top of its time on the wire.
pub type AnswerDelay = Box<dyn FnMut(u64) -> Duration + Send>;

/// How a packet link delivers the answer its device just gave: when, and how many times.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Delivery {
    /// How much later than at once.
    pub late: Duration,
    /// Sent twice.
    pub twice: bool,
}

/// Asked after each answer a packet device gives.
pub type PacketDelivery = Box<dyn FnMut() -> Delivery + Send>;

/// A byte link whose far end is a simulated device. Without a clock, answers are available as
/// soon as a write returns. With one, an empty read waits out its timeout on that clock (so
/// virtual time moves as it would on a wire), and an answer arrives when its frame would end:
/// after the request's and the answer's time on the wire (`with_line`) and any delay given to
/// it (`delay_answers`), never before an earlier answer.
pub struct MemoryByteLink<D: ByteDevice> {
    device: D,
    in_flight: VecDeque<(Duration, Vec<u8>)>,
    name: String,
    clock: Option<SharedClock>,
    line: LineState,
    delay: Option<AnswerDelay>,
    writes: u64,
}

impl<D: ByteDevice> MemoryByteLink<D> {
    /// A link to `device`, called `name` in messages.
    pub fn new(device: D, name: impl Into<String>) -> Self {
        Self {
            device,
            in_flight: VecDeque::new(),
            name: name.into(),
            clock: None,
            line: LineState::untimed(),
            delay: None,
            writes: 0,
        }
    }

    /// Makes empty reads wait out their timeout on `clock`, and answers arrive in its time.
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// Models a serial line at `baud` whose silences the host keeps, as on a serial port.
    pub fn with_line(mut self, baud: u32) -> Self {
        self.line = LineState::serial(baud);
        self
    }

    /// Delays the answer to the n-th write (from 0) by `delay(n)`: a module that answers late.
    pub fn delay_answers(mut self, delay: impl FnMut(u64) -> Duration + Send + 'static) -> Self {
        self.delay = Some(Box::new(delay));
        self
    }

    /// The simulated device at the far end.
    pub fn device(&mut self) -> &mut D {
        &mut self.device
    }

    fn now(&self) -> Duration {
        self.clock.as_ref().map_or(Duration::ZERO, |c| c.now())
    }

    /// Copies what has arrived by `now` into `buf`.
    fn take_arrived(&mut self, buf: &mut [u8], now: Duration) -> usize {
        let mut n = 0;
        while let Some((at, bytes)) = self.in_flight.front_mut() {
            if self.clock.is_some() && *at > now {
                break;
            }
            let Some(room) = buf.get_mut(n..) else { break };
            let k = room.len().min(bytes.len());
            if k == 0 {
                break;
            }
            for (slot, byte) in room.iter_mut().zip(bytes.drain(..k)) {
                *slot = byte;
            }
            n += k;
            if bytes.is_empty() {
                self.in_flight.pop_front();
            }
        }
        n
    }
}

impl<D: ByteDevice> ByteLink for MemoryByteLink<D> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        // A driver writes whole frames, so the frame ends here: the line then falls silent.
        let mut answer = self.device.receive(bytes);
        answer.extend(self.device.line_idle());
        let written = self.writes;
        self.writes = self.writes.saturating_add(1);
        if answer.is_empty() {
            return Ok(());
        }
        let late = self.delay.as_mut().map_or(Duration::ZERO, |d| d(written));
        let after_earlier = self.in_flight.back().map_or(Duration::ZERO, |(at, _)| *at);
        let starts = self
            .now()
            .saturating_add(self.line.wire_time(bytes.len()))
            .saturating_add(late)
            .max(after_earlier);
        let at = starts.saturating_add(self.line.wire_time(answer.len()));
        self.in_flight.push_back((at, answer));
        Ok(())
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        let now = self.now();
        let n = self.take_arrived(buf, now);
        if n > 0 || timeout.is_zero() {
            return Ok(n);
        }
        if let Some(clock) = &self.clock {
            let until = now.saturating_add(timeout);
            let next = self.in_flight.front().map(|(at, _)| *at);
            clock.sleep_until(next.map_or(until, |at| at.min(until)));
        }
        let now = self.now();
        Ok(self.take_arrived(buf, now))
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        if self.line.baud.is_some() {
            self.line.baud = Some(baud);
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!("simulated {}", self.name)
    }

    fn line(&mut self) -> Option<&mut LineState> {
        Some(&mut self.line)
    }
}

/// A packet link whose far end is a simulated device; empty reads behave as on `MemoryByteLink`.
/// An answer can be delivered late or twice (`deliver_with`); it never overtakes an earlier one.
pub struct MemoryPacketLink<D: PacketDevice> {
    device: D,
    pending: VecDeque<(Duration, [u8; 8])>,
    name: String,
    clock: Option<SharedClock>,
    delivery: Option<PacketDelivery>,
}

impl<D: PacketDevice> MemoryPacketLink<D> {
    /// A link to `device`, called `name` in messages.
    pub fn new(device: D, name: impl Into<String>) -> Self {
        Self {
            device,
            pending: VecDeque::new(),
            name: name.into(),
            clock: None,
            delivery: None,
        }
    }

    /// Makes empty reads wait out their timeout on `clock`, and late answers arrive in its time.
    pub fn with_clock(mut self, clock: SharedClock) -> Self {
        self.clock = Some(clock);
        self
    }

    /// Asks `delivery` after each answer how to deliver it (late, twice).
    pub fn deliver_with(mut self, delivery: impl FnMut() -> Delivery + Send + 'static) -> Self {
        self.delivery = Some(Box::new(delivery));
        self
    }

    fn now(&self) -> Duration {
        self.clock.as_ref().map_or(Duration::ZERO, |c| c.now())
    }

    /// The first answer, if it has arrived by `now`.
    fn take_arrived(&mut self, now: Duration) -> Option<[u8; 8]> {
        match self.pending.front() {
            Some((at, _)) if self.clock.is_none() || *at <= now => {
                self.pending.pop_front().map(|(_, p)| p)
            }
            _ => None,
        }
    }

    /// The simulated device at the far end.
    pub fn device(&mut self) -> &mut D {
        &mut self.device
    }
}

impl<D: PacketDevice> PacketLink for MemoryPacketLink<D> {
    fn send(&mut self, packet: &[u8; 8], _timeout: Duration) -> Result<(), LinkError> {
        if let Some(answer) = self.device.receive(packet) {
            let d = self.delivery.as_mut().map_or(Delivery::default(), |f| f());
            let after_earlier = self.pending.back().map_or(Duration::ZERO, |(at, _)| *at);
            let at = self.now().saturating_add(d.late).max(after_earlier);
            self.pending.push_back((at, answer));
            if d.twice {
                self.pending.push_back((at, answer));
            }
        }
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        let now = self.now();
        if let Some(p) = self.take_arrived(now) {
            return Ok(Some(p));
        }
        match (&self.clock, self.pending.front()) {
            (Some(clock), Some((at, _))) => clock.sleep_until((*at).min(now + timeout)),
            _ => wait_out(self.clock.as_ref(), timeout),
        }
        let now = self.now();
        Ok(self.take_arrived(now))
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
    use crate::link::line::wire_time;
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
    }

    #[test]
    fn answers_arrive_after_their_wire_time_and_their_delay_in_order() {
        let clock = VirtualClock::at_epoch();
        let mut link = MemoryByteLink::new(Echo, "echo")
            .with_clock(Arc::new(clock.clone()))
            .with_line(9600)
            .delay_answers(|n| Duration::from_millis(if n == 0 { 250 } else { 0 }));
        link.write_all(b"ab").unwrap();
        let mut buf = [0u8; 4];
        assert_eq!(link.read(&mut buf, Duration::ZERO).unwrap(), 0, "not yet");
        assert_eq!(link.read(&mut buf, Duration::from_millis(200)).unwrap(), 0);
        assert_eq!(clock.now(), Duration::from_millis(200));
        link.write_all(b"cd").unwrap();
        assert_eq!(link.read(&mut buf, Duration::from_millis(200)).unwrap(), 2);
        assert_eq!(&buf[..2], b"ba", "the late answer comes first");
        let first = Duration::from_millis(250) + wire_time(4, 9600);
        assert_eq!(clock.now(), first);
        assert_eq!(link.read(&mut buf, Duration::from_millis(200)).unwrap(), 2);
        assert_eq!(&buf[..2], b"dc");
        assert_eq!(clock.now(), first + wire_time(2, 9600));
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
