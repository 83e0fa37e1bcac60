//! The timing of a serial line, kept with the link between exchanges: its speed (how long a
//! frame takes on the wire), when the last frame on it ended, and whether it must settle after
//! a timeout. The exchange layer reads and updates it; the link only carries it, so every
//! module on one port shares it.

use crate::time::duration::parse_duration;
use std::time::Duration;

/// Bits a character takes on an 8N1 line: start, 8 data, stop.
pub const BITS_PER_CHAR: u64 = 10;

/// The longest frame gap a device may ask for.
pub const MAX_FRAME_GAP: Duration = Duration::from_secs(1);

/// The silence a device needs on the line before each request sent to it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrameGap {
    /// The protocol's own rule at the line's speed.
    #[default]
    Auto,
    /// This long, whatever the speed (a module that needs more; zero keeps none).
    Fixed(Duration),
}

impl FrameGap {
    /// Reads `auto` or a duration (`"5ms"`, `"0s"`) of at most `MAX_FRAME_GAP`.
    pub fn parse(text: &str) -> Result<Self, String> {
        let t = text.trim();
        if t.eq_ignore_ascii_case("auto") {
            return Ok(Self::Auto);
        }
        match parse_duration(t) {
            Ok(d) if d <= MAX_FRAME_GAP => Ok(Self::Fixed(d)),
            Ok(d) => Err(format!(
                "a frame gap of {d:?} is too long: use \"auto\" or at most 1s"
            )),
            Err(e) => Err(format!("{e}; or \"auto\"")),
        }
    }
}

/// Time `bytes` characters take on the wire at `baud` (8N1).
pub fn wire_time(bytes: usize, baud: u32) -> Duration {
    let bits = (bytes as u64).saturating_mul(BITS_PER_CHAR);
    Duration::from_nanos(bits.saturating_mul(1_000_000_000) / u64::from(baud.max(1)))
}

/// What the exchange layer knows about the line under a link.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct LineState {
    /// The line speed, when the host must keep the line's silences itself (a local serial
    /// port); `None` where something else times the line (a TCP device server) or there is no
    /// line (memory).
    pub baud: Option<u32>,
    /// When the last frame on the line ended, on the exchange layer's clock.
    pub quiet_since: Option<Duration>,
    /// After a timeout: the silence the line must keep before the next request, so that a late
    /// answer is heard and dropped instead of taken for the answer to that request.
    pub settle: Option<Duration>,
    /// When the first request still unanswered (timed out or cut short) left the wire, with no
    /// answer since: the next answer may be a late one, with the answers to the requests after
    /// it still to come.
    pub unanswered_since: Option<Duration>,
    /// Just opened: another program may have left a request on it unanswered, so the first
    /// request settles as after a timeout.
    pub just_opened: bool,
}

impl LineState {
    /// A serial line at `baud` whose silences the host keeps.
    pub fn serial(baud: u32) -> Self {
        Self {
            baud: Some(baud),
            ..Self::default()
        }
    }

    /// A link whose line (if any) someone else times.
    pub fn untimed() -> Self {
        Self::default()
    }

    /// Time `bytes` take on this line's wire (zero where the host does not time the line).
    pub fn wire_time(&self, bytes: usize) -> Duration {
        self.baud.map_or(Duration::ZERO, |b| wire_time(bytes, b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wire_time_counts_ten_bits_a_character() {
        assert_eq!(wire_time(8, 9600), Duration::from_nanos(8_333_333));
        assert_eq!(wire_time(1, 115_200), Duration::from_nanos(86_805));
        assert_eq!(LineState::untimed().wire_time(100), Duration::ZERO);
        assert_eq!(LineState::serial(9600).wire_time(6), wire_time(6, 9600));
    }

    #[test]
    fn frame_gaps_read_auto_or_a_bounded_duration() {
        assert_eq!(FrameGap::parse("auto"), Ok(FrameGap::Auto));
        assert_eq!(
            FrameGap::parse("5ms"),
            Ok(FrameGap::Fixed(Duration::from_millis(5)))
        );
        assert_eq!(FrameGap::parse("0s"), Ok(FrameGap::Fixed(Duration::ZERO)));
        assert!(FrameGap::parse("2s").unwrap_err().contains("too long"));
        assert!(FrameGap::parse("soon").unwrap_err().contains("auto"));
    }
}
