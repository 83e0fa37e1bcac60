//! Frames on a serial line in time: when each frame starts and ends on the wire at the line's
//! speed, and the silence before it. The simulator's strict timing and the line relay use it to
//! see the line as a module on it would.

use crate::link::line::wire_time;
use std::time::Duration;

/// Which end of the line sent a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum Side {
    /// The master (the host that polls).
    Master,
    /// The slaves (the modules that answer).
    Slave,
}

/// One frame as it was on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Frame {
    /// Who sent it.
    pub side: Side,
    /// When its first start bit went out.
    pub start: Duration,
    /// When its last stop bit ended.
    pub end: Duration,
    /// How many characters it held.
    pub bytes: usize,
    /// Silence on the line before it (from the end of the frame before, whoever sent it);
    /// `None` for the first frame, zero when it overlapped another.
    pub silence: Option<Duration>,
    /// Who sent the frame the silence counts from.
    pub after: Option<Side>,
}

/// The frames of one line, as they start, grow and end.
#[derive(Debug, Clone)]
pub struct Timeline {
    baud: u32,
    /// Bytes closer than this to the end of the frame before continue it (Modbus t1.5: a
    /// longer pause inside a frame breaks it).
    joint: Duration,
    open: [Option<Frame>; 2],
    last_end: Option<(Duration, Side)>,
}

fn slot(side: Side) -> usize {
    match side {
        Side::Master => 0,
        Side::Slave => 1,
    }
}

impl Timeline {
    /// An idle line at `baud`.
    pub fn new(baud: u32) -> Self {
        Self {
            baud,
            joint: wire_time(3, baud) / 2,
            open: [None, None],
            last_end: None,
        }
    }

    /// Time `bytes` characters take on this line.
    pub fn wire_time(&self, bytes: usize) -> Duration {
        wire_time(bytes, self.baud)
    }

    /// `bytes` characters from `side` reach the line at `at` and go out back to back after
    /// whatever `side` still has on the wire. Returns the frame they belong to (a new one,
    /// or the open one they continue) and whether they started it; a frame they close on the
    /// same side is returned as `closed`.
    pub fn send(&mut self, side: Side, at: Duration, bytes: usize) -> Sent {
        let open = self.open.get(slot(side)).copied().flatten();
        if let Some(mut frame) = open {
            if at <= frame.end.saturating_add(self.joint) {
                frame.end = frame.end.max(at).saturating_add(self.wire_time(bytes));
                frame.bytes = frame.bytes.saturating_add(bytes);
                self.set_open(side, Some(frame));
                return Sent {
                    frame,
                    started: false,
                    closed: None,
                };
            }
        }
        let closed = self.close(side);
        let (silence, after) = self.silence_before(side, at);
        let frame = Frame {
            side,
            start: at,
            end: at.saturating_add(self.wire_time(bytes)),
            bytes,
            silence,
            after,
        };
        self.set_open(side, Some(frame));
        Sent {
            frame,
            started: true,
            closed,
        }
    }

    /// Records a whole frame from `side` with known times (an answer the simulator timed
    /// itself); returns it with its silence.
    pub fn frame(&mut self, side: Side, start: Duration, end: Duration, bytes: usize) -> Frame {
        let _ = self.close(side);
        let (silence, after) = self.silence_before(side, start);
        let frame = Frame {
            side,
            start,
            end,
            bytes,
            silence,
            after,
        };
        self.ended(end, side);
        frame
    }

    /// Moves the end of the open frame on `side` to `at` when its last byte was handed over
    /// later than planned (the relay woke late): the silence after it counts from then.
    pub fn delivered(&mut self, side: Side, at: Duration) {
        if let Some(Some(frame)) = self.open.get_mut(slot(side)) {
            frame.end = frame.end.max(at);
        }
    }

    /// When the open frame on `side` leaves the wire, if there is one.
    pub fn busy_until(&self, side: Side) -> Option<Duration> {
        self.open.get(slot(side)).copied().flatten().map(|f| f.end)
    }

    /// Closes the open frame on `side` if no byte can continue it after `now`.
    pub fn close_if_idle(&mut self, side: Side, now: Duration) -> Option<Frame> {
        match self.busy_until(side) {
            Some(end) if now > end.saturating_add(self.joint) => self.close(side),
            _ => None,
        }
    }

    /// Closes the open frame on `side`, if any.
    pub fn close(&mut self, side: Side) -> Option<Frame> {
        let frame = self.open.get_mut(slot(side)).and_then(Option::take)?;
        self.ended(frame.end, side);
        Some(frame)
    }

    fn ended(&mut self, end: Duration, side: Side) {
        if self.last_end.map_or(true, |(last, _)| end >= last) {
            self.last_end = Some((end, side));
        }
    }

    fn set_open(&mut self, side: Side, frame: Option<Frame>) {
        if let Some(s) = self.open.get_mut(slot(side)) {
            *s = frame;
        }
    }

    fn silence_before(&self, side: Side, at: Duration) -> (Option<Duration>, Option<Side>) {
        let other = match side {
            Side::Master => Side::Slave,
            Side::Slave => Side::Master,
        };
        let still_sending = self.busy_until(other).map(|end| (end, other));
        match [self.last_end, still_sending]
            .into_iter()
            .flatten()
            .max_by_key(|(end, _)| *end)
        {
            Some((end, after)) => (Some(at.saturating_sub(end)), Some(after)),
            None => (None, None),
        }
    }
}

/// What `Timeline::send` did with some bytes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Sent {
    /// The frame the bytes are part of, as it stands.
    pub frame: Frame,
    /// The bytes started this frame.
    pub started: bool,
    /// The frame on the same side that these bytes ended by starting a new one.
    pub closed: Option<Frame>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn silence_is_counted_from_the_last_frame_on_the_line_whoever_sent_it() {
        let mut line = Timeline::new(9600);
        let request = line.send(Side::Master, ms(0), 8);
        assert!(request.started);
        assert_eq!(
            request.frame.silence, None,
            "nothing before the first frame"
        );
        let request_end = line.wire_time(8);
        assert_eq!(line.busy_until(Side::Master), Some(request_end));
        let answer = line.frame(Side::Slave, request_end, request_end + line.wire_time(6), 6);
        assert_eq!(answer.silence, Some(Duration::ZERO));
        let answer_end = answer.end;
        let next = line.send(Side::Master, answer_end + ms(2), 8);
        assert!(next.started);
        assert_eq!(
            next.closed.map(|f| f.bytes),
            Some(8),
            "the first request closed"
        );
        assert_eq!(next.frame.silence, Some(ms(2)));
        assert_eq!(next.frame.after, Some(Side::Slave));
        // A request with no answer: the next one counts from its own end.
        let late = next.frame.end + ms(5);
        let after = line.send(Side::Master, late, 8);
        assert_eq!(after.frame.silence, Some(ms(5)));
        assert_eq!(after.frame.after, Some(Side::Master));
    }

    #[test]
    fn bytes_close_together_continue_a_frame_and_queue_behind_it() {
        let mut line = Timeline::new(9600);
        line.send(Side::Master, ms(0), 2);
        let more = line.send(Side::Master, ms(1), 2);
        assert!(!more.started);
        assert_eq!(more.frame.bytes, 4);
        assert_eq!(more.frame.end, line.wire_time(4), "they wait for the line");
        assert_eq!(
            line.close_if_idle(Side::Master, ms(4)),
            None,
            "still sending"
        );
        let closed = line.close_if_idle(Side::Master, ms(10)).unwrap();
        assert_eq!(closed.bytes, 4);
        line.delivered(Side::Master, ms(20));
        let next = line.send(Side::Master, ms(12), 1);
        assert_eq!(next.frame.silence, Some(ms(12) - line.wire_time(4)));
    }
}
