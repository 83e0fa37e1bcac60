//! The shared serial line under a TRP-C29U driver: one request at a time, per-request timeout,
//! retries, and `--trace` output.

use crate::device::exchange::{exchange, ExchangeError, Timing, Tracer};
use crate::link::{ByteLink, LinkError};
use crate::time::clock::SharedClock;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::C29uError;

/// A byte link that several drivers (modules with different IDs on one line) take turns on.
pub type SharedLink = Arc<Mutex<Box<dyn ByteLink>>>;

/// Wraps a link so that several drivers can share it.
pub fn share(link: Box<dyn ByteLink>) -> SharedLink {
    Arc::new(Mutex::new(link))
}

/// How an attempt failed: worth another try (noise, silence) or final (the module said no).
pub(crate) enum Fault {
    /// Try again while retries last.
    Retry(C29uError),
    /// Give up at once.
    Final(C29uError),
}

/// One driver's view of the line: its link, clock, timing and trace.
pub(crate) struct Transport {
    link: SharedLink,
    clock: SharedClock,
    /// Wait for one answer.
    pub timeout: Duration,
    /// Further attempts after a timeout or a garbled answer.
    pub retries: u32,
    tracer: Option<Tracer>,
}

impl Transport {
    pub fn new(link: SharedLink, clock: SharedClock, timeout: Duration, retries: u32) -> Self {
        Self {
            link,
            clock,
            timeout,
            retries,
            tracer: None,
        }
    }

    pub fn set_tracer(&mut self, tracer: Option<Tracer>) {
        self.tracer = tracer;
    }

    /// The link in words, for messages.
    pub fn port(&self) -> String {
        self.lock().describe()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Box<dyn ByteLink>> {
        // A poisoned line only means a panicking test thread; the link itself is intact.
        self.link.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Changes the line speed (after the module was told to change its own).
    pub fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        self.lock().set_baud(baud)
    }

    /// One exchange; the line is held for exactly this long, so one dead module costs the
    /// others at most its own timeout.
    pub fn exchange(
        &mut self,
        request: &[u8],
        expect_answer: bool,
        gap: Option<Duration>,
        frame: impl FnMut(&[u8]) -> Option<Vec<u8>>,
    ) -> Result<Vec<u8>, ExchangeError> {
        let timing = Timing {
            timeout: self.timeout,
            gap,
        };
        let mut link = self.link.lock().unwrap_or_else(|e| e.into_inner());
        exchange(
            link.as_mut(),
            self.clock.as_ref(),
            request,
            expect_answer,
            timing,
            frame,
            &mut self.tracer,
        )
    }

    /// Runs `attempt` until it succeeds, fails finally, or the retries are used up.
    pub fn with_retries<T>(
        &mut self,
        mut attempt: impl FnMut(&mut Self) -> Result<T, Fault>,
    ) -> Result<T, C29uError> {
        let mut tries_left = self.retries;
        loop {
            match attempt(self) {
                Ok(value) => return Ok(value),
                Err(Fault::Final(e)) => return Err(e),
                Err(Fault::Retry(e)) if tries_left == 0 => return Err(e),
                Err(Fault::Retry(_)) => tries_left -= 1,
            }
        }
    }
}
