//! Faults queued for a simulated device's next answers (drop, garble, late, duplicate: the
//! words are `sim::faults`'s), put between an in-memory link and its simulator; a scenario
//! test or `verify` queues them. Lateness and the second copy are the link's business (it
//! holds the answer's arrival): the wrapper hands them over through
//! `AnswerFaults::take_delivery`, which the link asks after each answer.

use crate::link::far_end::{ByteDevice, PacketDevice};
use std::collections::VecDeque;
use std::sync::{Arc, Mutex};

/// Faults queued at most per device: each takes one answer, so a longer queue would not be
/// plausible noise but a dead line (make the device gone for that).
pub const MAX_QUEUED: usize = 64;

/// What happens to one answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AnswerFault {
    /// The answer never arrives.
    Drop,
    /// The answer arrives with one byte's top bit flipped.
    Garble,
    /// The answer arrives this much later than the device gave it.
    Late(std::time::Duration),
    /// The answer arrives twice, the copy right behind it.
    Duplicate,
}

pub use crate::link::memory::Delivery;

/// The faults waiting for a device's next answers; shared between the wrapper and whoever
/// queues them.
#[derive(Debug, Clone, Default)]
pub struct AnswerFaults(Arc<Mutex<Queued>>);

#[derive(Debug, Default)]
struct Queued {
    faults: VecDeque<AnswerFault>,
    /// The last answer's delivery, until the link takes it.
    delivery: Delivery,
}

impl AnswerFaults {
    fn queue(&self) -> std::sync::MutexGuard<'_, Queued> {
        crate::sync::lock(&self.0)
    }

    /// How the answer the device just gave is to be delivered (late, twice), taken once: the
    /// link asks after each answer.
    pub fn take_delivery(&self) -> Delivery {
        std::mem::take(&mut self.queue().delivery)
    }

    fn hand_over(&self, delivery: Delivery) {
        self.queue().delivery = delivery;
    }

    /// Queues `fault` for each of the next `n` answers (after those already queued); returns
    /// how many were queued (the queue holds `MAX_QUEUED` at most).
    pub fn push(&self, fault: AnswerFault, n: usize) -> usize {
        let mut q = self.queue();
        let room = MAX_QUEUED.saturating_sub(q.faults.len()).min(n);
        q.faults.extend(std::iter::repeat(fault).take(room));
        room
    }

    /// How many faults are waiting.
    pub fn pending(&self) -> usize {
        self.queue().faults.len()
    }

    /// Forgets the waiting faults.
    pub fn clear(&self) {
        let mut q = self.queue();
        q.faults.clear();
        q.delivery = Delivery::default();
    }

    fn next(&self) -> Option<AnswerFault> {
        self.queue().faults.pop_front()
    }
}

/// Flips the top bit of the middle byte of `answer`.
fn garble(mut answer: Vec<u8>) -> Vec<u8> {
    let at = answer.len() / 2;
    if let Some(b) = answer.get_mut(at) {
        *b ^= 0x80;
    }
    answer
}

/// What a lateness or a copy asks of the link.
fn delivery(fault: AnswerFault) -> Delivery {
    match fault {
        AnswerFault::Late(late) => Delivery { late, twice: false },
        AnswerFault::Duplicate => Delivery {
            late: std::time::Duration::ZERO,
            twice: true,
        },
        AnswerFault::Drop | AnswerFault::Garble => Delivery::default(),
    }
}

/// A simulated device whose answers suffer the faults queued in its `AnswerFaults`.
pub struct Faulty<D> {
    inner: D,
    faults: AnswerFaults,
}

impl<D> Faulty<D> {
    /// `inner`, with answers subject to `faults`.
    pub fn new(inner: D, faults: AnswerFaults) -> Self {
        Self { inner, faults }
    }

    fn apply(&self, answer: Vec<u8>) -> Vec<u8> {
        if answer.is_empty() {
            return answer;
        }
        match self.faults.next() {
            None => answer,
            Some(AnswerFault::Drop) => Vec::new(),
            Some(AnswerFault::Garble) => garble(answer),
            Some(AnswerFault::Duplicate) => [answer.as_slice(), answer.as_slice()].concat(),
            Some(fault) => {
                self.faults.hand_over(delivery(fault));
                answer
            }
        }
    }
}

impl<D: ByteDevice> ByteDevice for Faulty<D> {
    fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
        let answer = self.inner.receive(bytes);
        self.apply(answer)
    }

    fn line_idle(&mut self) -> Vec<u8> {
        let answer = self.inner.line_idle();
        self.apply(answer)
    }
}

impl<D: PacketDevice> PacketDevice for Faulty<D> {
    fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
        let answer = self.inner.receive(packet)?;
        match self.faults.next() {
            None => Some(answer),
            // USB packets carry a CRC: a garbled one is never delivered, so it is lost too.
            Some(AnswerFault::Drop | AnswerFault::Garble) => None,
            Some(fault) => {
                self.faults.hand_over(delivery(fault));
                Some(answer)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Echo;
    impl ByteDevice for Echo {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            bytes.to_vec()
        }
    }
    impl PacketDevice for Echo {
        fn receive(&mut self, packet: &[u8; 8]) -> Option<[u8; 8]> {
            Some(*packet)
        }
    }

    #[test]
    fn queued_faults_take_the_next_answers_in_order() {
        let faults = AnswerFaults::default();
        let mut d = Faulty::new(Echo, faults.clone());
        assert_eq!(faults.push(AnswerFault::Drop, 1), 1);
        assert_eq!(faults.push(AnswerFault::Garble, 1), 1);
        assert_eq!(ByteDevice::receive(&mut d, b"abc"), b"");
        assert_eq!(
            ByteDevice::receive(&mut d, b"abc"),
            [b'a', b'b' ^ 0x80, b'c']
        );
        assert_eq!(ByteDevice::receive(&mut d, b"abc"), b"abc");
        assert_eq!(faults.pending(), 0);
    }

    #[test]
    fn silence_does_not_use_up_a_fault_and_the_queue_is_bounded() {
        let faults = AnswerFaults::default();
        let mut d = Faulty::new(Echo, faults.clone());
        faults.push(AnswerFault::Drop, 1);
        assert_eq!(ByteDevice::receive(&mut d, b""), b"");
        assert_eq!(faults.pending(), 1, "no answer, nothing to drop");
        assert_eq!(faults.push(AnswerFault::Drop, 1000), MAX_QUEUED - 1);
        faults.clear();
        assert_eq!(faults.pending(), 0);
    }

    #[test]
    fn lateness_and_copies_are_handed_to_the_link_once() {
        let faults = AnswerFaults::default();
        let mut d = Faulty::new(Echo, faults.clone());
        let late = std::time::Duration::from_millis(300);
        faults.push(AnswerFault::Late(late), 1);
        faults.push(AnswerFault::Duplicate, 1);
        assert_eq!(ByteDevice::receive(&mut d, b"ab"), b"ab");
        assert_eq!(faults.take_delivery(), Delivery { late, twice: false });
        assert_eq!(faults.take_delivery(), Delivery::default(), "taken once");
        faults.push(AnswerFault::Duplicate, 1);
        assert_eq!(
            ByteDevice::receive(&mut d, b"ab"),
            b"abab",
            "a byte line carries both"
        );
        faults.push(AnswerFault::Duplicate, 1);
        assert_eq!(PacketDevice::receive(&mut d, &[2; 8]), Some([2; 8]));
        assert!(faults.take_delivery().twice);
    }

    #[test]
    fn a_garbled_usb_packet_is_lost() {
        let faults = AnswerFaults::default();
        let mut d = Faulty::new(Echo, faults.clone());
        faults.push(AnswerFault::Garble, 1);
        assert_eq!(PacketDevice::receive(&mut d, &[1; 8]), None);
        assert_eq!(PacketDevice::receive(&mut d, &[1; 8]), Some([1; 8]));
    }
}
