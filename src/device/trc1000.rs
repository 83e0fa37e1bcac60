//! TRC1000 driver: relay selection, switch and rotary reads over any packet link, matching each
//! answer to its request by its first byte and dropping stale packets (docs/trc1000-protocol.md). A
//! `Cancel` cuts a request short: nothing is sent once it is set, and the wait for an answer
//! looks at it between slices.

use crate::device::cancel::Cancel;
use crate::link::{LinkError, PacketLink};
use crate::protocol::trc1000::{
    rotary_delta, Command, InvalidRelay, Relay, Response, Rotary, RotaryValues, SwitchSet,
};
use crate::time::clock::{SharedClock, SystemClock};
use std::time::Duration;

/// How long a request waits for its answer unless told otherwise.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(500);

/// At most this many unrelated packets are dropped while waiting for one answer, so a board
/// (or link) that streams garbage cannot keep a request waiting whatever the clock says.
pub const MAX_DISCARDED: usize = 64;

/// Why a TRC1000 operation failed.
#[derive(Debug, thiserror::Error)]
pub enum Trc1000Error {
    /// The link failed (not found, permission, disconnected, USB error).
    #[error(transparent)]
    Link(#[from] LinkError),
    /// No matching answer arrived in time.
    #[error(
        "{board} did not answer {request} within {} ms{}: check that the board is powered and \
         connected, or allow more time (--timeout)",
        timeout.as_millis(),
        discarded_note(*discarded)
    )]
    Timeout {
        /// The board, as its link describes it.
        board: String,
        /// The request in words, such as `request input (41)`.
        request: String,
        /// How long the request waited.
        timeout: Duration,
        /// How many unrelated packets were dropped while waiting.
        discarded: usize,
    },
    /// A relay number outside 0-7; nothing was sent.
    #[error(transparent)]
    InvalidRelay(#[from] InvalidRelay),
    /// The caller's `Cancel` cut the request short (a run stopping): it says nothing of the
    /// board.
    #[error("{request} to {board} was cut short: the caller stopped waiting")]
    Cancelled {
        /// The board, as its link describes it.
        board: String,
        /// The request in words.
        request: String,
    },
}

fn discarded_note(n: usize) -> String {
    if n == 0 {
        String::new()
    } else {
        format!(" ({n} unrelated packets dropped)")
    }
}

impl Trc1000Error {
    /// Whether the board cannot be reached at all (not found, no permission, held by another
    /// program, disconnected), as
    /// opposed to a board that is there but misbehaves.
    pub fn is_unreachable(&self) -> bool {
        matches!(
            self,
            Trc1000Error::Link(
                LinkError::NotFound { .. }
                    | LinkError::PermissionDenied { .. }
                    | LinkError::Busy { .. }
                    | LinkError::Disconnected { .. }
            )
        )
    }
}

/// A TRC1000 board behind a packet link (USB, or memory to the simulator).
pub struct Trc1000<L: PacketLink> {
    link: L,
    clock: SharedClock,
    timeout: Duration,
    discarded: u64,
    cancel: Cancel,
    /// A request timed out, so its answer may still come: dropped before the next request,
    /// which would otherwise take it (same first byte) and leave every later reading one
    /// behind.
    late_answer_possible: bool,
}

impl<L: PacketLink> Trc1000<L> {
    /// A driver on `link` using real time and the default timeout.
    pub fn new(link: L) -> Self {
        Self::with_clock(link, SystemClock::shared())
    }

    /// A driver on `link` measuring its deadlines with `clock`.
    pub fn with_clock(link: L, clock: SharedClock) -> Self {
        Self {
            link,
            clock,
            timeout: DEFAULT_TIMEOUT,
            discarded: 0,
            cancel: Cancel::never(),
            late_answer_possible: false,
        }
    }

    /// Cuts requests short once `cancel` is set (`Trc1000Error::Cancelled`); `Cancel::never()`
    /// lets each wait its full timeout.
    pub fn set_cancel(&mut self, cancel: Cancel) {
        self.cancel = cancel;
    }

    /// Sets how long each request waits for its answer.
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// How long each request waits for its answer.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// The board in words, from its link.
    pub fn describe(&self) -> String {
        self.link.describe()
    }

    /// The link, such as the simulator behind a memory link in tests.
    pub fn link_mut(&mut self) -> &mut L {
        &mut self.link
    }

    /// Gives the link back.
    pub fn into_link(self) -> L {
        self.link
    }

    /// Unrelated packets dropped so far (stale answers to earlier requests, noise).
    pub fn discarded(&self) -> u64 {
        self.discarded
    }

    /// Selects relay `relay` (0-7); the board does not answer this command.
    pub fn select_relay(&mut self, relay: u8) -> Result<(), Trc1000Error> {
        let command = Command::SelectRelay(Relay::new(relay)?);
        self.unless_cancelled(command)?;
        self.drop_late_answers()?;
        self.link.send(&command.encode(), self.timeout)?;
        Ok(())
    }

    /// Selects relay `relay` (0-7) and confirms that a board took it: the selection gets no
    /// answer, and an OUT transfer can be taken without a board that acts on it (a host
    /// controller or hub may accept it for a board that hangs; a simulated board that is gone
    /// takes it silently), so a request input (41) follows and only its answer confirms the
    /// selection. Returns the switches that answer read.
    pub fn select_relay_confirmed(&mut self, relay: u8) -> Result<SwitchSet, Trc1000Error> {
        let selection = Command::SelectRelay(Relay::new(relay)?).describe();
        self.select_relay(relay)?;
        self.read_switches().map_err(|e| match e {
            Trc1000Error::Timeout {
                board,
                request,
                timeout,
                discarded,
            } => Trc1000Error::Timeout {
                board,
                request: format!("{request} after {selection}, so the selection is unconfirmed"),
                timeout,
                discarded,
            },
            other => other,
        })
    }

    /// Reads the 45 switches.
    pub fn read_switches(&mut self) -> Result<SwitchSet, Trc1000Error> {
        self.request(Command::RequestInput, |r| match r {
            Response::Inputs(s) => Some(s),
            _ => None,
        })
    }

    /// Reads the 14 rotary counters (two requests: `42` then `43`).
    pub fn read_rotaries(&mut self) -> Result<RotaryValues, Trc1000Error> {
        let r0 = self.request(Command::RequestRotary0, |r| match r {
            Response::Rotary0(v) => Some(v),
            _ => None,
        })?;
        let r1 = self.request(Command::RequestRotary1, |r| match r {
            Response::Rotary1(v) => Some(v),
            _ => None,
        })?;
        Ok(RotaryValues::from_packets(r0, r1))
    }

    /// `Cancelled` for `command` if the cancel is set.
    fn unless_cancelled(&self, command: Command) -> Result<(), Trc1000Error> {
        if self.cancel.is_cancelled() {
            return Err(Trc1000Error::Cancelled {
                board: self.link.describe(),
                request: command.describe(),
            });
        }
        Ok(())
    }

    /// After a timeout, drops what has arrived since (the late answer), without waiting: a
    /// USB read of nothing takes the shortest transfer timeout, so this is done only then.
    fn drop_late_answers(&mut self) -> Result<(), Trc1000Error> {
        if !std::mem::take(&mut self.late_answer_possible) {
            return Ok(());
        }
        for _ in 0..MAX_DISCARDED {
            if self.link.receive(Duration::ZERO)?.is_none() {
                break;
            }
            self.discarded = self.discarded.saturating_add(1);
        }
        Ok(())
    }

    /// Sends `command` and waits for the first packet `accept` takes, dropping others.
    fn request<T>(
        &mut self,
        command: Command,
        accept: impl Fn(Response) -> Option<T>,
    ) -> Result<T, Trc1000Error> {
        self.unless_cancelled(command)?;
        self.drop_late_answers()?;
        self.link.send(&command.encode(), self.timeout)?;
        let deadline = self.clock.now().saturating_add(self.timeout);
        let mut discarded = 0usize;
        let mut wait = self.timeout;
        loop {
            let asked = self.cancel.slice(wait);
            let before = self.clock.now();
            match self.link.receive(asked)? {
                Some(packet) => {
                    if let Some(value) = Response::decode(&packet).ok().and_then(&accept) {
                        return Ok(value);
                    }
                    discarded = discarded.saturating_add(1);
                    self.discarded = self.discarded.saturating_add(1);
                }
                // Nothing in all the time left (or on a link that does not wait: no time to
                // slice).
                None if asked == wait || self.clock.now() == before => break,
                None => {}
            }
            self.unless_cancelled(command)?;
            wait = deadline.saturating_sub(self.clock.now());
            if wait.is_zero() || discarded >= MAX_DISCARDED {
                break;
            }
        }
        self.late_answer_possible = true;
        Err(Trc1000Error::Timeout {
            board: self.link.describe(),
            request: command.describe(),
            timeout: self.timeout,
            discarded,
        })
    }
}

/// A rotary that moved between two reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RotaryChange {
    /// Which rotary.
    pub rotary: Rotary,
    /// Signed half-turns since the older read (wrap-aware).
    pub delta: i8,
    /// The counter in the newer read.
    pub value: u8,
}

impl RotaryChange {
    /// The rotary's name, such as `S41A`.
    pub fn name(&self) -> &'static str {
        self.rotary.name()
    }
}

/// The rotaries that moved from `old` to `new`, in wire order, with wrap-aware signed deltas.
pub fn rotary_changes(old: &RotaryValues, new: &RotaryValues) -> Vec<RotaryChange> {
    Rotary::ALL
        .iter()
        .filter_map(|&rotary| {
            let value = new.get(rotary);
            let delta = rotary_delta(old.get(rotary), value);
            (delta != 0).then_some(RotaryChange {
                rotary,
                delta,
                value,
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::link::far_end::PacketDevice;
    use crate::link::memory::MemoryPacketLink;
    use crate::sim::trc1000::Trc1000Sim;
    use crate::time::clock::VirtualClock;
    use std::collections::VecDeque;
    use std::sync::Arc;

    fn driver<D: PacketDevice>(device: D) -> Trc1000<MemoryPacketLink<D>> {
        Trc1000::with_clock(
            MemoryPacketLink::new(device, "TRC1000 unit 0"),
            Arc::new(VirtualClock::at_epoch()),
        )
    }

    /// A link that delivers queued extra packets before each real answer.
    struct Injecting<L> {
        inner: L,
        extra: VecDeque<[u8; 8]>,
        sent: Vec<[u8; 8]>,
    }

    impl<L: PacketLink> PacketLink for Injecting<L> {
        fn send(&mut self, p: &[u8; 8], t: Duration) -> Result<(), LinkError> {
            self.sent.push(*p);
            self.inner.send(p, t)
        }
        fn receive(&mut self, t: Duration) -> Result<Option<[u8; 8]>, LinkError> {
            match self.extra.pop_front() {
                Some(p) => Ok(Some(p)),
                None => self.inner.receive(t),
            }
        }
        fn describe(&self) -> String {
            self.inner.describe()
        }
    }

    fn injecting(
        sim: Trc1000Sim,
        extra: &[[u8; 8]],
    ) -> Trc1000<Injecting<MemoryPacketLink<Trc1000Sim>>> {
        Trc1000::with_clock(
            Injecting {
                inner: MemoryPacketLink::new(sim, "TRC1000 unit 0"),
                extra: extra.iter().copied().collect(),
                sent: Vec::new(),
            },
            Arc::new(VirtualClock::at_epoch()),
        )
    }

    /// A board that answers every request with the given packet (or not at all).
    struct Answers(Option<[u8; 8]>);
    impl PacketDevice for Answers {
        fn receive(&mut self, _: &[u8; 8]) -> Option<[u8; 8]> {
            self.0
        }
    }

    #[test]
    fn a_confirmed_selection_fails_when_no_board_answers_after_it() {
        let mut d = driver(Trc1000Sim::default());
        let switches = d.select_relay_confirmed(5).unwrap();
        assert_eq!(d.link_mut().device().relay().number(), 5);
        assert_eq!(switches, SwitchSet::default());

        let mut gone = driver(Answers(None));
        gone.select_relay(5)
            .expect("an OUT packet is taken, board or not");
        match gone.select_relay_confirmed(5) {
            Err(e @ Trc1000Error::Timeout { .. }) => {
                let text = e.to_string();
                assert!(
                    text.contains(
                        "did not answer request input (41) after select relay 5 (05), so the \
                         selection is unconfirmed"
                    ),
                    "{text}"
                );
            }
            other => panic!("expected no confirmation, got {other:?}"),
        }
    }

    #[test]
    fn a_stop_cuts_the_wait_for_a_silent_board_within_a_slice_and_sends_nothing_after() {
        use crate::device::cancel::CANCEL_SLICE;
        use crate::time::clock::Clock;
        use std::sync::atomic::AtomicUsize;
        let clock = VirtualClock::at_epoch();
        let link = Injecting {
            inner: MemoryPacketLink::new(Answers(None), "TRC1000 unit 0")
                .with_clock(Arc::new(clock.clone())),
            extra: VecDeque::new(),
            sent: Vec::new(),
        };
        let mut d = Trc1000::with_clock(link, Arc::new(clock.clone()));
        d.set_timeout(Duration::from_secs(1));
        let flag = Arc::new(AtomicUsize::new(0));
        d.set_cancel(Cancel::when_set(Arc::clone(&flag)));
        let signal = Duration::from_millis(350);
        clock.set_at(signal, flag, 15);
        match d.read_switches() {
            Err(e @ Trc1000Error::Cancelled { .. }) => {
                assert!(e.to_string().contains("cut short"), "{e}");
            }
            other => panic!("expected a cut request, got {other:?}"),
        }
        assert!(clock.now() <= signal + CANCEL_SLICE, "{:?}", clock.now());
        assert!(matches!(
            d.select_relay(3),
            Err(Trc1000Error::Cancelled { .. })
        ));
        assert_eq!(d.link_mut().sent.len(), 1, "nothing sent after the stop");
    }

    /// A link that streams garbage forever and never advances time.
    struct Garbage;
    impl PacketLink for Garbage {
        fn send(&mut self, _: &[u8; 8], _: Duration) -> Result<(), LinkError> {
            Ok(())
        }
        fn receive(&mut self, _: Duration) -> Result<Option<[u8; 8]>, LinkError> {
            Ok(Some([0xEE; 8]))
        }
        fn describe(&self) -> String {
            "noisy board".into()
        }
    }

    /// A link whose board has gone away.
    struct Unplugged;
    impl PacketLink for Unplugged {
        fn send(&mut self, _: &[u8; 8], _: Duration) -> Result<(), LinkError> {
            Err(LinkError::Disconnected {
                what: "TRC1000 unit 0".into(),
                detail: "gone".into(),
            })
        }
        fn receive(&mut self, _: Duration) -> Result<Option<[u8; 8]>, LinkError> {
            Ok(None)
        }
        fn describe(&self) -> String {
            "TRC1000 unit 0".into()
        }
    }

    #[test]
    fn reads_switches_and_rotaries_from_the_simulator() {
        let mut sim = Trc1000Sim::new();
        sim.press("S3").unwrap();
        sim.press("S41").unwrap();
        sim.turn("S41A", 6).unwrap();
        sim.turn("S40", -4).unwrap();
        let mut trc = driver(sim);
        assert_eq!(
            trc.read_switches().unwrap().pressed_names(),
            vec!["S3", "S41"]
        );
        let r = trc.read_rotaries().unwrap();
        assert_eq!(r.get(Rotary::S41A), 6);
        assert_eq!(r.get(Rotary::S40), 252);
        assert_eq!(r.get(Rotary::S44B), 0);
        assert_eq!(trc.discarded(), 0);
    }

    #[test]
    fn select_relay_reaches_the_board_and_bad_numbers_send_nothing() {
        let mut trc = driver(Trc1000Sim::new());
        trc.select_relay(5).unwrap();
        assert_eq!(trc.link_mut().device().relay().number(), 5);
        let e = trc.select_relay(8).unwrap_err();
        assert!(
            matches!(e, Trc1000Error::InvalidRelay(InvalidRelay(8))),
            "{e}"
        );
        assert_eq!(trc.link_mut().device().relay_commands(), 1);
        assert!(!e.is_unreachable());
    }

    #[test]
    fn select_relay_sends_05_then_relay_shifted_by_two() {
        let mut trc = injecting(Trc1000Sim::new(), &[]);
        trc.select_relay(5).unwrap();
        assert_eq!(trc.link_mut().sent, vec![[0x05, 0x14, 0, 0, 0, 0, 0, 0]]);
    }

    #[test]
    fn stale_and_garbage_packets_before_the_answer_are_dropped() {
        let mut sim = Trc1000Sim::new();
        sim.press("S45").unwrap();
        let stale = [
            [0xC2, 9, 9, 9, 9, 9, 9, 9],
            [0x00; 8],
            [0xC3, 1, 1, 1, 1, 1, 1, 1],
            [0xFF; 8],
        ];
        let mut trc = injecting(sim, &stale);
        assert_eq!(trc.read_switches().unwrap().pressed_names(), vec!["S45"]);
        assert_eq!(trc.discarded(), 4);
    }

    #[test]
    fn an_answer_that_comes_after_its_timeout_is_not_taken_for_the_next() {
        // Fails without drop_late_answers: the late (empty) reading answers the next request,
        // and every reading after is one behind.
        let clock = VirtualClock::at_epoch();
        let late = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
        let first = std::sync::Arc::clone(&late);
        let board = std::sync::Arc::new(std::sync::Mutex::new(Trc1000Sim::new()));
        let link = MemoryPacketLink::new(std::sync::Arc::clone(&board), "TRC1000 unit 0")
            .with_clock(Arc::new(clock.clone()))
            .deliver_with(move || crate::link::memory::Delivery {
                late: if first.swap(false, std::sync::atomic::Ordering::SeqCst) {
                    Duration::from_millis(300)
                } else {
                    Duration::ZERO
                },
                twice: false,
            });
        let mut trc = Trc1000::with_clock(link, Arc::new(clock.clone()));
        trc.set_timeout(Duration::from_millis(250));
        assert!(matches!(
            trc.read_switches(),
            Err(Trc1000Error::Timeout { .. })
        ));
        assert!(!late.load(std::sync::atomic::Ordering::SeqCst));
        board.lock().unwrap().press("S45").unwrap();
        clock.advance(Duration::from_secs(1));
        assert_eq!(trc.read_switches().unwrap().pressed_names(), vec!["S45"]);
        assert_eq!(trc.read_switches().unwrap().pressed_names(), vec!["S45"]);
        assert_eq!(trc.discarded(), 1, "the late answer");
    }

    #[test]
    fn a_stale_input_answer_does_not_pass_for_a_rotary_answer() {
        let mut sim = Trc1000Sim::new();
        sim.turn("S44A", 2).unwrap();
        sim.turn("S44B", 4).unwrap();
        let stale = [[0xC1, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF]];
        let mut trc = injecting(sim, &stale);
        let r = trc.read_rotaries().unwrap();
        assert_eq!((r.get(Rotary::S44A), r.get(Rotary::S44B)), (2, 4));
        assert_eq!(trc.discarded(), 1);
        let sent: Vec<u8> = trc.link_mut().sent.iter().map(|p| p[0]).collect();
        assert_eq!(sent, vec![0x42, 0x43]);
    }

    #[test]
    fn a_wrong_answer_times_out_naming_the_board_and_request() {
        let mut trc = driver(Answers(Some([0xC3, 0, 0, 0, 0, 0, 0, 0])));
        trc.set_timeout(Duration::from_millis(200));
        let e = trc.read_switches().unwrap_err();
        match &e {
            Trc1000Error::Timeout {
                board,
                request,
                timeout,
                discarded,
            } => {
                assert_eq!(board, "simulated TRC1000 unit 0");
                assert_eq!(request, "request input (41)");
                assert_eq!(*timeout, Duration::from_millis(200));
                assert_eq!(*discarded, 1);
            }
            other => panic!("not a timeout: {other}"),
        }
        let msg = e.to_string();
        assert!(
            msg.contains("request input (41)") && msg.contains("200 ms"),
            "{msg}"
        );
        assert!(!e.is_unreachable());
    }

    #[test]
    fn no_answer_is_a_timeout() {
        let mut trc = driver(Answers(None));
        let e = trc.read_rotaries().unwrap_err();
        assert!(
            matches!(&e, Trc1000Error::Timeout { request, discarded: 0, .. } if request == "request rotary0 (42)"),
            "{e}"
        );
    }

    #[test]
    fn endless_garbage_ends_in_a_timeout_even_when_time_stands_still() {
        let mut trc = Trc1000::with_clock(Garbage, Arc::new(VirtualClock::at_epoch()));
        let e = trc.read_switches().unwrap_err();
        assert!(
            matches!(
                e,
                Trc1000Error::Timeout {
                    discarded: MAX_DISCARDED,
                    ..
                }
            ),
            "{e}"
        );
    }

    #[test]
    fn a_vanished_board_is_unreachable() {
        let mut trc = Trc1000::new(Unplugged);
        let e = trc.read_switches().unwrap_err();
        assert!(e.is_unreachable(), "{e}");
        assert!(e.to_string().contains("disconnected"), "{e}");
    }

    #[test]
    fn rotary_changes_are_named_signed_and_wrap_aware() {
        let mut sim = Trc1000Sim::new();
        sim.turn("S41A", -1).unwrap(); // 0xFF
        sim.turn("S38", 10).unwrap();
        let mut trc = driver(sim);
        let before = trc.read_rotaries().unwrap();
        trc.link_mut().device().turn("S41A", 2).unwrap(); // 0xFF -> 0x01
        trc.link_mut().device().turn("S38", -3).unwrap();
        let after = trc.read_rotaries().unwrap();
        let changes: Vec<(&str, i8, u8)> = rotary_changes(&before, &after)
            .iter()
            .map(|c| (c.name(), c.delta, c.value))
            .collect();
        assert_eq!(changes, vec![("S41A", 2, 1), ("S38", -3, 7)]);
        assert!(rotary_changes(&after, &after).is_empty());
    }
}
