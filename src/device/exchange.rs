//! One request/answer exchange on a byte link: keep the silence the line needs before the
//! request (dropping whatever arrives meanwhile), send, and collect the answer until the
//! protocol says it is complete, the line falls silent after it, or time runs out.
//!
//! The silence is counted from the end of the last frame on the line, whoever sent it: an
//! answer, our own request that gets none, stray bytes. After a timeout the line must stay
//! silent for one more timeout before the next request, so a late answer is heard and dropped
//! instead of being taken for the answer to the request after it; an answer taken after a
//! timeout may itself be late, so the line then stays silent as long as it may have been late
//! (since the first unanswered request), the answers to the later tries being dropped in turn;
//! a port just opened settles as after a timeout (another program may have left a request
//! unanswered). Matching an answer to its request cannot replace this: a DO and a DI read
//! have answers of the same shape. The waits sleep; a request
//! already late is sent at once. Every buffer is bounded by the longest valid answer. A
//! `Cancel` cuts an exchange short: nothing is sent once it is set, and the waits look at it
//! between slices.

use crate::device::cancel::{Cancel, CANCEL_SLICE};
use crate::link::line::{FrameGap, LineState};
use crate::link::{ByteLink, LinkError};
use crate::protocol::c29u::{frame_gap, Protocol};
use crate::time::clock::Clock;
use std::time::Duration;

/// How long after a write returns a USB-serial adapter may start sending the bytes: they go
/// out with its next USB frame, at most 1 ms away at full speed.
pub const ADAPTER_LATENCY: Duration = Duration::from_millis(1);

/// How an exchange waits.
#[derive(Debug, Clone, Copy)]
pub struct Timing {
    /// How long to wait for the whole answer, once the request has left the wire.
    pub timeout: Duration,
    /// Silence after some bytes that ends an answer whose end the protocol cannot tell
    /// (Modbus: 3.5 character times); `None` when only the protocol ends an answer.
    pub gap: Option<Duration>,
    /// The silence to keep on a timed serial line before the request.
    pub frame_gap: FrameGap,
    /// The protocol spoken, whose rule `FrameGap::Auto` follows (`c29u::frame_gap`).
    pub protocol: Protocol,
    /// The longest answer the protocol has; more bytes than this are not an answer.
    pub max_answer: usize,
    /// How long the answer can be, when the protocol tells: on a timed line the rest of it
    /// cannot be in before its bytes have crossed the wire, so the exchange sleeps until then
    /// instead of waking for every byte.
    pub answer_len: Option<AnswerLen>,
}

/// The lengths an answer to a request can have.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AnswerLen {
    /// The shortest answer that can come (an exception): until it could be whole, the
    /// exchange cannot tell which answer is coming.
    pub shortest: usize,
    /// The answer the request normally gets.
    pub normal: usize,
}

impl Timing {
    /// The silence to keep before a request on `line`: none where the host does not time the
    /// line (TCP device servers time their own; memory has no wire).
    pub fn silence_on(&self, line: &LineState) -> Duration {
        line.baud.map_or(Duration::ZERO, |baud| {
            frame_gap(self.protocol, self.frame_gap, baud)
        })
    }
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
        /// Bytes that arrived before time ran out (at most the longest answer).
        received: Vec<u8>,
    },
    /// More bytes came than the longest answer has, with no answer among them.
    #[error("{} bytes and no answer among them", received.len())]
    Overflow {
        /// The first bytes that came.
        received: Vec<u8>,
    },
    /// The line never fell silent long enough to send (another master, a babbling device).
    #[error("the line did not fall silent: {heard} bytes came in {within:?}")]
    Busy {
        /// How many bytes were dropped while waiting.
        heard: usize,
        /// How long it waited.
        within: Duration,
    },
    /// The caller's `Cancel` was set: cut short, says nothing of the device.
    #[error("cut short: the caller stopped waiting")]
    Cancelled,
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
/// Once `cancel` is set it ends in `Cancelled` within a `CANCEL_SLICE`, and sends nothing.
#[allow(clippy::too_many_arguments)]
pub fn exchange(
    link: &mut dyn ByteLink,
    clock: &dyn Clock,
    request: &[u8],
    expect_answer: bool,
    timing: Timing,
    frame: impl FnMut(&[u8]) -> Option<Vec<u8>>,
    tracer: &mut Option<Tracer>,
    cancel: &Cancel,
) -> Result<Vec<u8>, ExchangeError> {
    let mut line = link.line().copied().unwrap_or_default();
    let outcome = send_and_collect(
        link,
        clock,
        &mut line,
        request,
        expect_answer,
        &timing,
        frame,
        tracer,
        cancel,
    );
    if let Some(kept) = link.line() {
        *kept = line;
    }
    outcome
}

#[allow(clippy::too_many_arguments)]
fn send_and_collect(
    link: &mut dyn ByteLink,
    clock: &dyn Clock,
    line: &mut LineState,
    request: &[u8],
    expect_answer: bool,
    timing: &Timing,
    mut frame: impl FnMut(&[u8]) -> Option<Vec<u8>>,
    tracer: &mut Option<Tracer>,
    cancel: &Cancel,
) -> Result<Vec<u8>, ExchangeError> {
    if expect_answer && std::mem::take(&mut line.just_opened) {
        // Another program's request may still be answered: heard and dropped, as after a
        // timeout, with whatever the port held already. A request that gets no answer (host
        // OK, fed from a shell loop) cannot take it, and leaves the settling to the next.
        line.quiet_since = Some(clock.now());
        line.settle = Some(timing.timeout);
    }
    keep_silence(link, clock, line, timing, cancel)?;
    if let Some(trace) = tracer.as_mut() {
        trace(Direction::Sent, request);
    }
    link.write_all(request)?;
    let mut now = clock.now();
    // A USB-serial adapter returns from the write before the bytes are out: they are on the
    // wire until `request_end` at the earliest.
    let request_end = now.saturating_add(line.wire_time(request.len()));
    if !expect_answer {
        // No answer will say when the request really ended: allow for its leaving late.
        let latency = line.baud.map_or(Duration::ZERO, |_| ADAPTER_LATENCY);
        line.quiet_since = Some(request_end.saturating_add(latency));
        return Ok(Vec::new());
    }
    line.quiet_since = Some(request_end);
    let deadline = request_end.saturating_add(timing.timeout);
    let mut chunk = [0u8; 256];
    // Room for a whole answer of the longest kind at once: no regrowth as bytes come.
    let mut received = Vec::with_capacity(timing.max_answer.min(chunk.len()));
    loop {
        let left = deadline.saturating_sub(now);
        let cancelled = cancel.is_cancelled();
        if left.is_zero() || cancelled {
            // The module may still answer (after a stop too: the next request is the end's
            // safe state): the next request waits until the line has been silent for the
            // settling time.
            line.quiet_since = Some(now);
            line.settle = Some(timing.timeout);
            line.unanswered_since.get_or_insert(request_end);
            trace_received(tracer, &received);
            return Err(if cancelled {
                ExchangeError::Cancelled
            } else {
                ExchangeError::Timeout { received }
            });
        }
        let wait = match timing.gap {
            // At most 29 ms (t3.5 at 1200 baud): shorter than a slice.
            Some(gap) if !received.is_empty() => gap.min(left),
            _ => cancel.slice(left),
        };
        crate::guardian::pulse::beat();
        let n = link.read(&mut chunk, wait)?;
        // On a wire the answer has ended when its last byte is in: stamped before parsing.
        let read_at = clock.now();
        now = read_at;
        let Some(bytes) = chunk.get(..n).filter(|b| !b.is_empty()) else {
            if timing.gap.is_some() && !received.is_empty() && wait < left {
                // The line fell silent after an answer the protocol could not end itself:
                // hand it over whole, the parser judges it.
                line.quiet_since = Some(read_at);
                trace_received(tracer, &received);
                return Ok(received);
            }
            continue;
        };
        let room = timing.max_answer.saturating_sub(received.len());
        if bytes.len() > room {
            received.extend_from_slice(bytes.get(..room).unwrap_or_default());
            line.quiet_since = Some(read_at);
            trace_received(tracer, &received);
            return Err(ExchangeError::Overflow { received });
        }
        received.extend_from_slice(bytes);
        if let Some(answer) = frame(&received) {
            line.quiet_since = Some(read_at);
            if let Some(since) = line.unanswered_since.take() {
                // This answer may be a late one to an earlier request, with the answers to the
                // requests after it still to come (same shape, and neither a DO and a DI read
                // nor ASCII say whose): the next request waits until the line has been silent
                // as long as this answer may have been late, and never less than a timeout.
                line.settle = Some(timing.timeout.max(read_at.saturating_sub(since)));
            }
            trace_received(tracer, &answer);
            return Ok(answer);
        }
        // Two or more characters still to come (one costs a wake-up either way): one sleep for
        // them, then one look, where waiting for bytes would wake once a character. Until the
        // shortest answer could be whole, only that much is certain to come; past it (no
        // shorter answer ended) the normal answer is.
        if let (Some(len), Some(_)) = (timing.answer_len, line.baud) {
            let expected = if received.len() < len.shortest {
                len.shortest
            } else {
                len.normal
            };
            let rest = expected.saturating_sub(received.len());
            if rest >= 2 {
                clock.sleep_until(read_at.saturating_add(line.wire_time(rest)).min(deadline));
                now = clock.now();
            }
        }
    }
}

/// Waits until the line has been silent as long as it must be before a request: the frame gap,
/// or after a timeout the settling time. Bytes that come meanwhile are dropped and restart the
/// count; a line that never falls silent within a timeout more ends in `Busy`.
fn keep_silence(
    link: &mut dyn ByteLink,
    clock: &dyn Clock,
    line: &mut LineState,
    timing: &Timing,
    cancel: &Cancel,
) -> Result<(), ExchangeError> {
    let gap = timing.silence_on(line);
    let started = clock.now();
    let mut now = started;
    let mut heard = 0usize;
    let mut scratch = [0u8; 256];
    loop {
        if cancel.is_cancelled() {
            return Err(ExchangeError::Cancelled);
        }
        let needed = line.settle.map_or(gap, |settle| settle.max(gap));
        // Bytes still coming that long after the wait began: a wait cut into slices has not
        // waited that long for silence.
        let waited = line.quiet_since.unwrap_or(now).saturating_sub(started);
        if heard > 0 && waited > timing.timeout.saturating_add(needed) {
            return Err(ExchangeError::Busy {
                heard,
                within: waited,
            });
        }
        let quiet_at = line.quiet_since.map_or(now, |t| t.saturating_add(needed));
        if now < quiet_at {
            // Listen rather than sleep: bytes that arrive restart the count, and a wait that
            // hears nothing has shown the line silent, so no look is needed after it (one
            // system call for the silence and the check for stale input).
            // In slices even when nothing can cancel (the end's writes): a settle after a late
            // answer may outlast the stall limit, and each slice is a sign of life of the loop
            // (`guardian::pulse`).
            let wait = quiet_at.saturating_sub(now).min(CANCEL_SLICE);
            crate::guardian::pulse::beat();
            let n = link.read(&mut scratch, wait)?;
            let after = clock.now();
            if n > 0 {
                heard = heard.saturating_add(n);
                line.quiet_since = Some(after);
                now = after;
                continue;
            }
            if after >= quiet_at {
                line.settle = None;
                return Ok(());
            }
            // A slice of the wait ended, or a link that cannot wait (memory without a clock)
            // came back early.
            clock.sleep_until(now.saturating_add(wait));
            now = clock.now();
            continue;
        }
        // Already late: one look at what came meanwhile; usually nothing, and the request goes.
        match link.read(&mut scratch, Duration::ZERO)? {
            0 => {
                line.settle = None;
                return Ok(());
            }
            n => {
                heard = heard.saturating_add(n);
                now = clock.now();
                line.quiet_since = Some(now);
            }
        }
    }
}

fn trace_received(tracer: &mut Option<Tracer>, received: &[u8]) {
    if let (Some(trace), false) = (tracer.as_mut(), received.is_empty()) {
        trace(Direction::Received, received);
    }
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
    use crate::link::far_end::ByteDevice;
    use crate::link::memory::MemoryByteLink;
    use crate::time::clock::VirtualClock;
    use std::collections::VecDeque;
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

    fn t35(baud: u32) -> Duration {
        crate::protocol::c29u_modbus::silence_gap(baud)
    }

    fn timing(gap: Option<u64>) -> Timing {
        Timing {
            timeout: Duration::from_millis(200),
            gap: gap.map(Duration::from_millis),
            frame_gap: FrameGap::Auto,
            protocol: Protocol::Modbus,
            max_answer: 64,
            answer_len: None,
        }
    }

    /// Answers every request with `answer`, noting the clock time each request arrived.
    struct Stamped {
        clock: VirtualClock,
        answer: Vec<u8>,
        heard_at: Arc<Mutex<Vec<Duration>>>,
    }
    impl ByteDevice for Stamped {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            self.heard_at.lock().unwrap().push(self.clock.now());
            // `~**` (host OK) gets no answer.
            if bytes.starts_with(b"~") {
                Vec::new()
            } else {
                self.answer.clone()
            }
        }
    }

    fn stamped(
        answer: &[u8],
    ) -> (
        VirtualClock,
        Arc<Mutex<Vec<Duration>>>,
        MemoryByteLink<Stamped>,
    ) {
        let clock = VirtualClock::at_epoch();
        let heard_at = Arc::new(Mutex::new(Vec::new()));
        let device = Stamped {
            clock: clock.clone(),
            answer: answer.to_vec(),
            heard_at: heard_at.clone(),
        };
        let link = MemoryByteLink::new(device, "t").with_clock(Arc::new(clock.clone()));
        (clock, heard_at, link)
    }

    fn ask(
        link: &mut dyn ByteLink,
        clock: &VirtualClock,
        expect: bool,
    ) -> Result<Vec<u8>, ExchangeError> {
        let request: &[u8] = if expect { b"ask\r" } else { b"~**\r" };
        exchange(
            link,
            clock,
            request,
            expect,
            timing(None),
            line_end,
            &mut None,
            &Cancel::never(),
        )
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
            &Cancel::never(),
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
            &Cancel::never(),
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
            &Cancel::never(),
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
            &mut None,
            &Cancel::never(),
        )
        .unwrap()
        .is_empty());
        assert_eq!(clock.now(), Duration::ZERO);
    }

    #[test]
    fn requests_keep_the_silence_after_the_answer_and_after_an_unanswered_request() {
        let (clock, heard_at, link) = stamped(b"!01\r");
        let mut link = link.with_line(9600);
        let wire = |n| crate::link::line::wire_time(n, 9600);
        ask(&mut link, &clock, true).unwrap();
        let answer_end = wire(4) + wire(4);
        assert_eq!(
            clock.now(),
            answer_end,
            "the answer arrives as its frame ends"
        );
        ask(&mut link, &clock, true).unwrap();
        ask(&mut link, &clock, false).unwrap();
        ask(&mut link, &clock, true).unwrap();
        let heard = heard_at.lock().unwrap().clone();
        assert_eq!(heard[0], Duration::ZERO, "the first request goes at once");
        assert_eq!(heard[1], answer_end + t35(9600), "t3.5 after the answer");
        let second_end = heard[1] + wire(4) + wire(4);
        assert_eq!(heard[2], second_end + t35(9600));
        assert_eq!(
            heard[3],
            heard[2] + ADAPTER_LATENCY + wire(4) + t35(9600),
            "an unanswered request is on the wire until its last byte has left the adapter"
        );
    }

    #[test]
    fn the_silence_belongs_to_the_line_whoever_asks_next() {
        // Two drivers' exchanges on one link: the gap is kept across them, from the line's state.
        let (clock, heard_at, link) = stamped(b"!01\r");
        let mut link: Box<dyn ByteLink> = Box::new(link.with_line(115_200));
        ask(link.as_mut(), &clock, true).unwrap();
        let end = clock.now();
        let mut other = timing(None);
        other.frame_gap = FrameGap::Fixed(Duration::from_millis(5));
        exchange(
            link.as_mut(),
            &clock,
            b"x\r",
            true,
            other,
            line_end,
            &mut None,
            &Cancel::never(),
        )
        .unwrap();
        assert_eq!(heard_at.lock().unwrap()[1], end + Duration::from_millis(5));
        assert_eq!(t35(115_200), Duration::from_micros(1750));
    }

    #[test]
    fn a_late_request_is_not_delayed_and_untimed_links_add_nothing() {
        let (clock, heard_at, link) = stamped(b"!01\r");
        let mut link = link.with_line(9600);
        ask(&mut link, &clock, true).unwrap();
        clock.advance(Duration::from_millis(50));
        let before = clock.now();
        ask(&mut link, &clock, true).unwrap();
        assert_eq!(heard_at.lock().unwrap()[1], before);

        let (clock, heard_at, mut untimed) = stamped(b"!01\r");
        ask(&mut untimed, &clock, true).unwrap();
        ask(&mut untimed, &clock, false).unwrap();
        ask(&mut untimed, &clock, true).unwrap();
        assert!(
            heard_at.lock().unwrap().iter().all(|t| t.is_zero()),
            "no gap over TCP or memory"
        );
        assert_eq!(clock.now(), Duration::ZERO);
    }

    #[test]
    fn after_a_timeout_a_late_answer_is_dropped_before_the_next_request() {
        // The first answer comes 250 ms late (timeout 200 ms); the next request must not take it.
        let (clock, heard_at, link) = stamped(b"!01\r");
        let mut link = link.delay_answers(|n| Duration::from_millis(if n == 0 { 250 } else { 0 }));
        let first = ask(&mut link, &clock, true).unwrap_err();
        assert!(matches!(first, ExchangeError::Timeout { ref received } if received.is_empty()));
        assert_eq!(clock.now(), Duration::from_millis(200));
        let second = exchange(
            &mut link,
            &clock,
            b"next\r",
            true,
            timing(None),
            line_end,
            &mut None,
            &Cancel::never(),
        );
        assert_eq!(second.unwrap(), b"!01\r");
        let heard = heard_at.lock().unwrap().clone();
        assert_eq!(
            heard[1],
            Duration::from_millis(250 + 200),
            "the late answer at 250 ms was heard, then 200 ms of silence kept"
        );
        assert!(
            link.read(&mut [0u8; 8], Duration::ZERO).unwrap() == 0,
            "nothing left over"
        );
    }

    /// Answers every request with its own text in lower case, so an answer names its request.
    struct Lower;
    impl ByteDevice for Lower {
        fn receive(&mut self, bytes: &[u8]) -> Vec<u8> {
            bytes.to_ascii_lowercase()
        }
    }

    fn lower_late(
        late: impl FnMut(u64) -> Duration + Send + 'static,
    ) -> (VirtualClock, MemoryByteLink<Lower>) {
        let clock = VirtualClock::at_epoch();
        let link = MemoryByteLink::new(Lower, "lower")
            .with_clock(Arc::new(clock.clone()))
            .with_line(9600)
            .delay_answers(late);
        (clock, link)
    }

    fn send(
        link: &mut dyn ByteLink,
        clock: &VirtualClock,
        request: &[u8],
    ) -> Result<Vec<u8>, ExchangeError> {
        exchange(
            link,
            clock,
            request,
            true,
            timing(None),
            line_end,
            &mut None,
            &Cancel::never(),
        )
    }

    #[test]
    fn an_answer_taken_after_a_timeout_keeps_the_line_silent_as_long_as_it_was_late() {
        // Every answer comes 500 ms late against a 200 ms timeout: the retry takes the first
        // try's answer, and the retry's own answer is still to come when the next request,
        // one whose answer has the same shape, would go after one timeout of silence.
        let (clock, mut link) = lower_late(|_| Duration::from_millis(500));
        assert!(matches!(
            send(&mut link, &clock, b"DO\r"),
            Err(ExchangeError::Timeout { .. })
        ));
        assert_eq!(send(&mut link, &clock, b"DO\r").unwrap(), b"do\r");
        let mut other = Vec::new();
        for _ in 0..3 {
            match send(&mut link, &clock, b"DI\r") {
                Ok(answer) => {
                    other = answer;
                    break;
                }
                Err(ExchangeError::Timeout { received }) => assert!(received.is_empty()),
                Err(e) => panic!("{e}"),
            }
        }
        assert_eq!(
            other, b"di\r",
            "the DO read's late answer taken for the DI read's"
        );
    }

    #[test]
    fn a_port_just_opened_drops_the_answer_to_another_programs_request() {
        // Another program asked and gave up; its answer comes 150 ms after this one opened.
        let (clock, mut link) = lower_late(|n| Duration::from_millis(if n == 0 { 150 } else { 0 }));
        link.write_all(b"OLD\r").unwrap();
        link.line().unwrap().just_opened = true;
        assert_eq!(send(&mut link, &clock, b"NEW\r").unwrap(), b"new\r");
        let old_end = Duration::from_millis(150) + crate::link::line::wire_time(8, 9600);
        assert!(
            clock.now() > old_end + Duration::from_millis(200),
            "{:?}",
            clock.now()
        );
        // Only once: the next request keeps the frame gap alone.
        let before = clock.now();
        send(&mut link, &clock, b"NEW\r").unwrap();
        assert!(clock.now() - before < Duration::from_millis(20));
    }

    #[test]
    fn a_quiet_line_after_a_timeout_costs_nothing_later() {
        let (clock, heard_at, link) = stamped(b"");
        let mut link = link;
        ask(&mut link, &clock, true).unwrap_err();
        clock.advance(Duration::from_secs(1));
        let before = clock.now();
        ask(&mut link, &clock, true).unwrap_err();
        assert_eq!(heard_at.lock().unwrap()[1], before);
    }

    /// A peer that, once asked, sends `01 46 77` nonstop: every read finds a buffer full,
    /// 100 µs apart.
    struct Flooding {
        clock: VirtualClock,
        line: LineState,
        started: bool,
    }
    impl ByteLink for Flooding {
        fn write_all(&mut self, _bytes: &[u8]) -> Result<(), LinkError> {
            self.started = true;
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
            if !self.started {
                self.clock.advance(timeout);
                return Ok(0);
            }
            self.clock.advance(Duration::from_micros(100));
            for (slot, byte) in buf.iter_mut().zip([0x01, 0x46, 0x77].iter().cycle()) {
                *slot = *byte;
            }
            Ok(buf.len())
        }
        fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
            Ok(())
        }
        fn describe(&self) -> String {
            "flood".into()
        }
        fn line(&mut self) -> Option<&mut LineState> {
            Some(&mut self.line)
        }
    }

    #[test]
    fn a_flooding_peer_fills_no_more_than_the_longest_answer_and_then_blocks_the_line() {
        let clock = VirtualClock::at_epoch();
        let mut link = Flooding {
            clock: clock.clone(),
            line: LineState::untimed(),
            started: false,
        };
        let log = Arc::new(Mutex::new(Vec::new()));
        let log2 = log.clone();
        let mut tracer: Option<Tracer> =
            Some(Box::new(move |_, b| log2.lock().unwrap().push(b.len())));
        let mut ask = |tracer: &mut Option<Tracer>| {
            exchange(
                &mut link,
                &clock,
                b"x",
                true,
                timing(Some(2)),
                |_| None,
                tracer,
                &Cancel::never(),
            )
        };
        match ask(&mut tracer) {
            Err(ExchangeError::Overflow { received }) => assert_eq!(received.len(), 64),
            other => panic!("expected an overflow, got {other:?}"),
        }
        assert_eq!(
            *log.lock().unwrap(),
            vec![1, 64],
            "the trace shows at most the longest answer"
        );
        let before = clock.now();
        match ask(&mut None) {
            Err(ExchangeError::Busy { heard, within }) => {
                assert!(heard > 64);
                assert!(within <= Duration::from_millis(201));
            }
            other => panic!("expected a busy line, got {other:?}"),
        }
        assert!(
            clock.now() - before <= Duration::from_millis(201),
            "given up after a timeout"
        );
    }

    /// A link that notes the timeout of every read: each is one wait (or one look) on a port.
    struct Reads<L> {
        inner: L,
        timeouts: Vec<Duration>,
    }
    impl<L: ByteLink> ByteLink for Reads<L> {
        fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
            self.inner.write_all(bytes)
        }
        fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
            self.timeouts.push(timeout);
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
    }

    #[test]
    fn the_silence_is_one_wait_that_also_checks_for_stale_input() {
        let (clock, heard_at, link) = stamped(b"!01\r");
        let mut link = Reads {
            inner: link.with_line(115_200),
            timeouts: Vec::new(),
        };
        ask(&mut link, &clock, true).unwrap();
        link.timeouts.clear();
        ask(&mut link, &clock, true).unwrap();
        // The wait for the silence, then the wait for the answer: no separate look (no
        // zero-timeout read), no sleep besides.
        assert_eq!(link.timeouts.len(), 2, "{:?}", link.timeouts);
        assert_eq!(link.timeouts[0], t35(115_200));
        assert!(link.timeouts.iter().all(|t| !t.is_zero()));
        let heard = heard_at.lock().unwrap().clone();
        let answer_end = crate::link::line::wire_time(8, 115_200);
        assert_eq!(heard[1], answer_end + t35(115_200));
    }

    #[test]
    fn bytes_heard_during_the_silence_restart_it_from_their_arrival() {
        let (clock, heard_at, link) = stamped(b"!02\r");
        let mut link = link.with_line(9600);
        let wire = |n| crate::link::line::wire_time(n, 9600);
        // Sent without waiting for an answer, which comes anyway while the next request waits
        // for the silence: its last byte is in at 4 + 4 characters.
        exchange(
            &mut link,
            &clock,
            b"x\r\r\r",
            false,
            timing(None),
            line_end,
            &mut None,
            &Cancel::never(),
        )
        .unwrap();
        let got = ask(&mut link, &clock, true).unwrap();
        assert_eq!(got, b"!02\r", "the stray answer was dropped");
        let heard = heard_at.lock().unwrap().clone();
        assert_eq!(
            heard[1],
            wire(4) + wire(4) + t35(9600),
            "t3.5 from the stray answer's end, not from when the wait would have ended"
        );
    }

    /// A wire at `baud` in virtual time: the answer's bytes come one a character time after
    /// the request has left; every read is noted.
    struct Trickle {
        clock: VirtualClock,
        line: LineState,
        answer: Vec<u8>,
        due: VecDeque<(Duration, u8)>,
        reads: usize,
    }
    impl ByteLink for Trickle {
        fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
            let start = self.clock.now() + self.line.wire_time(bytes.len());
            let char_time = self.line.wire_time(1);
            for (k, &b) in (1u32..).zip(&self.answer) {
                self.due.push_back((start + char_time * k, b));
            }
            Ok(())
        }
        fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
            self.reads += 1;
            if let Some(&(at, _)) = self.due.front() {
                if at > self.clock.now() && !timeout.is_zero() {
                    let until = at.min(self.clock.now() + timeout);
                    self.clock.sleep_until(until);
                }
            } else {
                self.clock.advance(timeout);
            }
            let mut n = 0;
            while let Some(&(at, b)) = self.due.front() {
                if at > self.clock.now() || n == buf.len() {
                    break;
                }
                buf[n] = b;
                n += 1;
                self.due.pop_front();
            }
            Ok(n)
        }
        fn set_baud(&mut self, _baud: u32) -> Result<(), LinkError> {
            Ok(())
        }
        fn describe(&self) -> String {
            "trickle".into()
        }
        fn line(&mut self) -> Option<&mut LineState> {
            Some(&mut self.line)
        }
    }

    #[test]
    fn an_answer_of_known_length_is_slept_for_not_woken_for_byte_by_byte() {
        let clock = VirtualClock::at_epoch();
        let answer = b"abcde\r".to_vec();
        let mut link = Trickle {
            clock: clock.clone(),
            line: LineState::serial(9600),
            answer: answer.clone(),
            due: VecDeque::new(),
            reads: 0,
        };
        let mut known = timing(None);
        known.frame_gap = FrameGap::Fixed(Duration::ZERO);
        known.answer_len = Some(AnswerLen {
            shortest: 5,
            normal: 6,
        });
        let got = exchange(
            &mut link,
            &clock,
            b"q\r",
            true,
            known,
            line_end,
            &mut None,
            &Cancel::never(),
        )
        .unwrap();
        assert_eq!(got, answer);
        let wire = |n| crate::link::line::wire_time(n, 9600);
        // The bytes come a character apart after the request.
        let done = wire(2) + wire(1) * 6;
        assert_eq!(clock.now(), done, "done as the last byte is in");
        // A look for stale input, the wait for the first byte, a look after sleeping until the
        // shortest answer could be in, a look after sleeping for the last byte.
        assert_eq!(link.reads, 4, "one read a byte would be 7");
        assert_eq!(link.line.quiet_since, Some(done));

        // The shortest answer is whole as soon as it is in.
        link.answer = b"abcd\r".to_vec();
        link.reads = 0;
        let start = clock.now();
        let got = exchange(
            &mut link,
            &clock,
            b"q\r",
            true,
            known,
            line_end,
            &mut None,
            &Cancel::never(),
        )
        .unwrap();
        assert_eq!(got, b"abcd\r");
        assert_eq!(clock.now(), start + wire(2) + wire(1) + wire(4));
        assert_eq!(link.reads, 3);
    }

    #[test]
    fn stale_input_is_dropped_before_the_request() {
        let (clock, _heard, link) = stamped(b"!02\r");
        let mut link = link.with_line(9600);
        // An answer to a request nobody waits for any more (sent without expecting one).
        exchange(
            &mut link,
            &clock,
            b"x\r",
            false,
            timing(None),
            line_end,
            &mut None,
            &Cancel::never(),
        )
        .unwrap();
        clock.advance(Duration::from_millis(100));
        let got = ask(&mut link, &clock, true).unwrap();
        assert_eq!(got, b"!02\r");
        assert_eq!(link.read(&mut [0u8; 8], Duration::ZERO).unwrap(), 0);
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
