//! The shared serial line under a TRP-C29U driver: one request at a time, the silence before
//! each, per-request timeout, retries, `--trace` output, and the caller's `Cancel` (a stop cuts
//! the exchange under way short, and no retry follows).

use crate::device::cancel::Cancel;
use crate::device::exchange::{exchange, AnswerLen, ExchangeError, Timing, Tracer};
use crate::link::line::FrameGap;
use crate::link::{ByteLink, LinkError};
use crate::protocol::c29u::Protocol;
use crate::protocol::c29u_modbus::MAX_FRAME_LEN;
use crate::time::clock::SharedClock;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::C29uError;

/// The longest ASCII answer is 16 characters (`!01C29M090703`, checksum, CR); four times that
/// leaves room for noise before a whole answer and bounds what a babbling line can fill.
pub const ASCII_MAX_ANSWER: usize = 64;

/// A byte link that several drivers (modules with different IDs on one line) take turns on.
pub type SharedLink = Arc<Mutex<Box<dyn ByteLink>>>;

/// Wraps a link so that several drivers can share it.
pub fn share(link: Box<dyn ByteLink>) -> SharedLink {
    Arc::new(Mutex::new(link))
}

/// How an attempt failed: worth another try (noise, silence) or final (the module said no).
pub(crate) enum AttemptFault {
    /// Try again while retries last.
    Retry(C29uError),
    /// Give up at once.
    Final(C29uError),
}

/// One driver's view of the line: its link, clock, timing, trace and cancellation.
pub(crate) struct Transport {
    link: SharedLink,
    clock: SharedClock,
    /// Wait for one answer.
    pub timeout: Duration,
    /// Further attempts after a timeout or a garbled answer.
    pub retries: u32,
    protocol: Protocol,
    frame_gap: FrameGap,
    tracer: Option<Tracer>,
    cancel: Cancel,
}

impl Transport {
    pub fn new(
        link: SharedLink,
        clock: SharedClock,
        timeout: Duration,
        retries: u32,
        protocol: Protocol,
        frame_gap: FrameGap,
    ) -> Self {
        Self {
            link,
            clock,
            timeout,
            retries,
            protocol,
            frame_gap,
            tracer: None,
            cancel: Cancel::never(),
        }
    }

    pub fn set_tracer(&mut self, tracer: Option<Tracer>) {
        self.tracer = tracer;
    }

    pub fn set_cancel(&mut self, cancel: Cancel) {
        self.cancel = cancel;
    }

    /// The link in words, for messages.
    pub fn port(&self) -> String {
        self.lock().describe()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Box<dyn ByteLink>> {
        // A poisoned line only means a panicking test thread; the link itself is intact.
        crate::sync::lock(&self.link)
    }

    /// Changes the line speed (after the module was told to change its own).
    pub fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        self.lock().set_baud(baud)
    }

    /// One exchange; the line is held for exactly this long, so one dead module costs the
    /// others at most its own timeout (and, at the next request, the settling after it). Once
    /// the cancel is set it is cut short within a slice (`ExchangeError::Cancelled`).
    /// `answer_len`: how long the answer can be, where the protocol tells.
    pub fn exchange(
        &mut self,
        request: &[u8],
        expect_answer: bool,
        gap: Option<Duration>,
        answer_len: Option<AnswerLen>,
        frame: impl FnMut(&[u8]) -> Option<Vec<u8>>,
    ) -> Result<Vec<u8>, ExchangeError> {
        let max_answer = match self.protocol {
            Protocol::Modbus => MAX_FRAME_LEN,
            Protocol::Ascii => ASCII_MAX_ANSWER,
        };
        let timing = Timing {
            timeout: self.timeout,
            gap,
            frame_gap: self.frame_gap,
            protocol: self.protocol,
            max_answer,
            answer_len,
        };
        let mut link = crate::sync::lock(&self.link);
        exchange(
            link.as_mut(),
            self.clock.as_ref(),
            request,
            expect_answer,
            timing,
            frame,
            &mut self.tracer,
            &self.cancel,
        )
    }

    /// Runs `attempt` until it succeeds, fails finally, or the retries are used up; a cut
    /// exchange fails finally (`exchange_fault`), so a stop is never retried.
    pub fn with_retries<T>(
        &mut self,
        mut attempt: impl FnMut(&mut Self) -> Result<T, AttemptFault>,
    ) -> Result<T, C29uError> {
        let mut tries_left = self.retries;
        loop {
            match attempt(self) {
                Ok(value) => return Ok(value),
                Err(AttemptFault::Final(e)) => return Err(e),
                Err(AttemptFault::Retry(e)) if tries_left == 0 => return Err(e),
                Err(AttemptFault::Retry(_)) => tries_left -= 1,
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device::c29u::{share, C29u, C29uError, C29uOptions};
    use crate::link::far_end::ByteDevice;
    use crate::link::memory::MemoryByteLink;
    use crate::time::clock::{Clock, VirtualClock};

    struct Silent;
    impl ByteDevice for Silent {
        fn receive(&mut self, _bytes: &[u8]) -> Vec<u8> {
            Vec::new()
        }
    }

    #[test]
    fn a_silent_module_holds_the_line_for_every_try_and_the_settling_before_each_retry() {
        // What config::feeding counts: tries x (silence + request + timeout), the silence
        // before a retry being the timeout.
        for (retries, baud) in [(0u32, 9600), (2, 9600), (3, 1200)] {
            let clock = VirtualClock::at_epoch();
            let link = MemoryByteLink::new(Silent, "silent")
                .with_clock(Arc::new(clock.clone()))
                .with_line(baud);
            let options = C29uOptions {
                baud,
                timeout: Duration::from_millis(100),
                retries,
                ..C29uOptions::default()
            };
            let mut dev =
                C29u::new(share(Box::new(link)), Arc::new(clock.clone()), options).unwrap();
            assert!(matches!(
                dev.read_counters(),
                Err(C29uError::Timeout { .. })
            ));
            let request = crate::link::line::wire_time(8, baud);
            let tries = retries + 1;
            let expected = (request + Duration::from_millis(100)) * tries
                + Duration::from_millis(100) * retries;
            assert_eq!(clock.now(), expected, "{retries} retries at {baud} baud");
        }
    }
}
