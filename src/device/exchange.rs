//! One request/answer exchange on a byte link: flush stale input, send, and collect the answer
//! until the protocol says it is complete, the line falls silent after it, or time runs out.

use crate::link::{ByteLink, LinkError};
use crate::time::clock::Clock;
use std::time::Duration;

/// How an exchange waits.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    /// How long to wait for the whole answer.
    pub timeout: Duration,
    /// Silence after some bytes that ends an answer whose end the protocol cannot tell
    /// (Modbus: 3.5 character times); `None` when only the protocol ends an answer.
    pub gap: Option<Duration>,
}

/// How an exchange ended without an answer.
#[derive(Debug, thiserror::Error)]
pub enum ExchangeError {
    /// The link failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// No complete answer in time; `received` holds whatever did arrive.
    #[error("no complete answer in time")]
    Timeout {
        /// Bytes that arrived before time ran out.
        received: Vec<u8>,
    },
}

/// Which way a traced frame went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Host to device.
    Sent,
    /// Device to host.
    Received,
}

/// Somewhere to report every frame sent and received (`--trace`).
pub type Tracer = Box<dyn FnMut(Direction, &[u8]) + Send>;

/// Sends `request` and, when `expect_answer`, collects the answer: `frame` looks at everything
/// received so far and returns the answer once it holds a whole one (leading noise cut off).
pub fn exchange(
    link: &mut dyn ByteLink,
    clock: &dyn Clock,
    request: &[u8],
    expect_answer: bool,
    timing: Timing,
    mut frame: impl FnMut(&[u8]) -> Option<Vec<u8>>,
    tracer: &mut Option<Tracer>,
) -> Result<Vec<u8>, ExchangeError> {
    // Anything already waiting is a late answer to an earlier request.
    link.discard_input()?;
    if let Some(trace) = tracer.as_mut() {
        trace(Direction::Sent, request);
    }
    link.write_all(request)?;
    if !expect_answer {
        return Ok(Vec::new());
    }
    let deadline = clock.now().saturating_add(timing.timeout);
    let mut received = Vec::new();
    let mut chunk = [0u8; 256];
    loop {
        let left = deadline.saturating_sub(clock.now());
        if left.is_zero() {
            return Err(timed_out(received, tracer));
        }
        let wait = match timing.gap {
            Some(gap) if !received.is_empty() => gap.min(left),
            _ => left,
        };
        let n = link.read(&mut chunk, wait)?;
        match chunk.get(..n) {
            Some(bytes) if !bytes.is_empty() => {
                received.extend_from_slice(bytes);
                if let Some(answer) = frame(&received) {
                    if let Some(trace) = tracer.as_mut() {
                        trace(Direction::Received, &answer);
                    }
                    return Ok(answer);
                }
            }
            _ => {
                if timing.gap.is_some() && !received.is_empty() && wait < left {
                    // The line fell silent after an answer the protocol could not end itself:
                    // hand it over whole, the parser judges it.
                    if let Some(trace) = tracer.as_mut() {
                        trace(Direction::Received, &received);
                    }
                    return Ok(received);
                }
            }
        }
    }
}

fn timed_out(received: Vec<u8>, tracer: &mut Option<Tracer>) -> ExchangeError {
    if let (Some(trace), false) = (tracer.as_mut(), received.is_empty()) {
        trace(Direction::Received, &received);
    }
    ExchangeError::Timeout { received }
}

/// Formats a frame for `--trace`: hex, plus printable text for ASCII frames.
pub fn format_frame(direction: Direction, bytes: &[u8], as_text: bool) -> String {
    let arrow = match direction {
        Direction::Sent => ">>",
        Direction::Received => "<<",
    };
    let hex: Vec<String> = bytes.iter().map(|b| format!("{b:02X}")).collect();
    if as_text {
        let text: String = bytes
            .iter()
            .map(|&b| match b {
                b'\r' => "\\r".to_string(),
                0x20..=0x7E => (b as char).to_string(),
                _ => format!("\\x{b:02x}"),
            })
            .collect();
        format!("{arrow} {}  \"{text}\"", hex.join(" "))
    } else {
        format!("{arrow} {}", hex.join(" "))
    }
}

/// A packet link that reports every packet sent and received to a tracer (`trc --trace`).
pub struct TracedPacketLink<L: crate::link::PacketLink> {
    inner: L,
    tracer: Tracer,
}

impl<L: crate::link::PacketLink> TracedPacketLink<L> {
    /// Wraps `inner`, reporting its packets to `tracer`.
    pub fn new(inner: L, tracer: Tracer) -> Self {
        Self { inner, tracer }
    }
}

impl<L: crate::link::PacketLink> crate::link::PacketLink for TracedPacketLink<L> {
    fn send(&mut self, packet: &[u8; 8], timeout: Duration) -> Result<(), LinkError> {
        (self.tracer)(Direction::Sent, packet);
        self.inner.send(packet, timeout)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        let packet = self.inner.receive(timeout)?;
        if let Some(p) = &packet {
            (self.tracer)(Direction::Received, p);
        }
        Ok(packet)
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::memory::MemoryByteLink;
    use crate::sim::ByteDevice;
    use crate::time::clock::VirtualClock;
    use std::sync::{Arc, Mutex};

    /// Answers with a fixed reply, recording what it heard.
    struct Canned(Vec<u8>, Arc<Mutex<Vec<u8>>>);
    impl ByteDevice for Canned {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            self.1.lock().unwrap().extend_from_slice(bytes);
            self.0.clone()
        }
    }

    fn line_end(buf: &[u8]) -> Option<Vec<u8>> {
        let end = buf.iter().position(|&b| b == b'\r')?;
        Some(buf[..=end].to_vec())
    }

    fn timing(gap: Option<u64>) -> Timing {
        Timing {
            timeout: Duration::from_millis(200),
            gap: gap.map(Duration::from_millis),
        }
    }

    #[test]
    fn complete_answer_is_cut_at_its_end_and_traced() {
        let clock = VirtualClock::at_epoch();
        let heard = Arc::new(Mutex::new(Vec::new()));
        let mut link = MemoryByteLink::new(Canned(b"!01\rjunk".to_vec(), heard.clone()), "t")
            .with_clock(Arc::new(clock.clone()));
        let log = Arc::new(Mutex::new(Vec::new()));
        let log2 = log.clone();
        let mut tracer: Option<Tracer> = Some(Box::new(move |d, b| {
            log2.lock().unwrap().push((d, b.to_vec()))
        }));
        let got = exchange(
            &mut link,
            &clock,
            b"$01M\r",
            true,
            timing(None),
            line_end,
            &mut tracer,
        )
        .unwrap();
        assert_eq!(got, b"!01\r");
        assert_eq!(*heard.lock().unwrap(), b"$01M\r");
        assert_eq!(
            *log.lock().unwrap(),
            vec![
                (Direction::Sent, b"$01M\r".to_vec()),
                (Direction::Received, b"!01\r".to_vec())
            ]
        );
    }

    #[test]
    fn silence_times_out_with_what_arrived_and_takes_the_timeout() {
        let clock = VirtualClock::at_epoch();
        let mut link = MemoryByteLink::new(Canned(b"!01".to_vec(), Default::default()), "t")
            .with_clock(Arc::new(clock.clone()));
        let err = exchange(
            &mut link,
            &clock,
            b"x",
            true,
            timing(None),
            line_end,
            &mut None,
        )
        .unwrap_err();
        match err {
            ExchangeError::Timeout { received } => assert_eq!(received, b"!01"),
            other => panic!("expected a timeout, got {other}"),
        }
        assert_eq!(clock.now(), Duration::from_millis(200));
    }

    #[test]
    fn a_gap_ends_an_answer_the_protocol_cannot_end() {
        let clock = VirtualClock::at_epoch();
        let mut link = MemoryByteLink::new(Canned(vec![1, 0xC6, 0], Default::default()), "t")
            .with_clock(Arc::new(clock.clone()));
        let got = exchange(
            &mut link,
            &clock,
            b"x",
            true,
            timing(Some(2)),
            |_| None,
            &mut None,
        )
        .unwrap();
        assert_eq!(got, vec![1, 0xC6, 0]);
        assert_eq!(
            clock.now(),
            Duration::from_millis(2),
            "waited one gap, not the timeout"
        );
    }

    #[test]
    fn no_answer_expected_returns_at_once() {
        let clock = VirtualClock::at_epoch();
        let mut link = MemoryByteLink::new(Canned(Vec::new(), Default::default()), "t")
            .with_clock(Arc::new(clock.clone()));
        assert!(exchange(
            &mut link,
            &clock,
            b"~**\r",
            false,
            timing(None),
            line_end,
            &mut None
        )
        .unwrap()
        .is_empty());
        assert_eq!(clock.now(), Duration::ZERO);
    }

    #[test]
    fn traced_packet_link_reports_both_directions() {
        use crate::link::memory::MemoryPacketLink;
        use crate::link::PacketLink;
        use crate::sim::trc1000::Trc1000Sim;
        let log = Arc::new(Mutex::new(Vec::new()));
        let log2 = log.clone();
        let mut link = TracedPacketLink::new(
            MemoryPacketLink::new(Trc1000Sim::new(), "panel"),
            Box::new(move |d, b| log2.lock().unwrap().push(format_frame(d, b, false))),
        );
        link.send(&[0x41, 0, 0, 0, 0, 0, 0, 0], Duration::ZERO)
            .unwrap();
        assert!(link.receive(Duration::ZERO).unwrap().is_some());
        assert_eq!(
            *log.lock().unwrap(),
            vec![">> 41 00 00 00 00 00 00 00", "<< C1 00 00 00 00 00 00 00"]
        );
    }

    #[test]
    fn trace_lines_show_hex_and_text() {
        assert_eq!(
            format_frame(Direction::Sent, b"$01M\r", true),
            ">> 24 30 31 4D 0D  \"$01M\\r\""
        );
        assert_eq!(
            format_frame(Direction::Received, &[1, 0x46], false),
            "<< 01 46"
        );
    }
}
