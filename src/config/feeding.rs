//! Whether the runner can feed each host watchdog in time, whatever an exchange may take.
//!
//! The scan loop feeds a module's watchdog on its own deadline: between ticks (the loop's
//! sleep wakes for it) and before every exchange inside a tick. The loop does one thing at a
//! time, so a feed that falls due while an exchange is under way waits for it: in the worst
//! case the longest exchange any device of the rig can take (a silent module: every attempt's
//! timeout, and before each the silence the line must keep), then the feed's own way to the
//! module (the line settling after that failure, and the request's time on the wire), and the
//! loop's own wake-up lateness. A feed is therefore sent that much before the watchdog would
//! fire, and at least every quarter of its timeout; a watchdog so short that this leaves less
//! than a tenth of its timeout between feeds is refused, with the arithmetic.
//!
//! The arithmetic covers modules that answer within their timeout or not at all. One that
//! answers later than its timeout makes its line keep silent after the late answer is taken for
//! as long as it may have been late (`device::exchange`: up to that whole exchange again), so a
//! feed on that line can come later than counted here. Counting that for every rig would
//! nearly double the shortest watchdog accepted for a fault a rig rarely has; its worst outcome
//! is safe: the module's watchdog fires, its outputs take their safe value, and the runner
//! finds it in safe mode and takes control again.
//!
//! Opening a lost module's link again costs no more than one of its exchanges (a device server
//! gets the module's timeout to connect, `runtime::devices::open`). The loop feeds between
//! handlers too, but a handler that computes for long between two of its exchanges delays a
//! feed by that long: `WAKE_RESERVE` allows for a few milliseconds of it, no more.

use super::device::{C29uConfig, DeviceConfig, Port};
use super::error::ProblemKind;
use super::reader::{shown, Reader, TableRef};
use crate::link::line::wire_time;
use crate::protocol::c29u_modbus::silence_gap;
use crate::time::duration::format_duration;
use std::collections::BTreeMap;
use std::time::Duration;
use toml::de::DeValue;

/// How long a TRC1000 request waits for its answer in a run (the board answers within a few
/// milliseconds); sending waits as long at most, so a silent board costs twice this.
pub const TRC1000_TIMEOUT: Duration = Duration::from_millis(250);

/// What the loop may take to get to a due feed besides exchanges: waking from its sleep
/// (milliseconds under load, on a virtual CPU) and a tick's own work between two exchanges.
pub const WAKE_RESERVE: Duration = Duration::from_millis(20);

/// The longest request the runner sends in a run (Modbus writes of one register or eight
/// coils, ASCII commands with checksum: 8-11 bytes), in bytes.
pub const LONGEST_REQUEST: usize = 16;

/// The watchdog feed's request (Modbus: 8 bytes; ASCII `~**`: 4), in bytes.
pub const FEED_REQUEST: usize = 8;

/// A watchdog is fed at most this many times per timeout.
pub const MOST_FEEDS_PER_TIMEOUT: u32 = 10;

/// The worst one device's exchange can take.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LongestExchange {
    /// The device.
    pub device: String,
    /// Tries (1 + retries).
    pub attempts: u32,
    /// Before each try: the silence its line must keep (after a timeout on it, the timeout).
    pub silence: Duration,
    /// The request's time on the wire.
    pub request: Duration,
    /// How long each try waits for its answer (TRC1000: to send, then to receive).
    pub wait: Duration,
}

impl LongestExchange {
    /// All of it.
    pub fn total(&self) -> Duration {
        self.silence
            .saturating_add(self.request)
            .saturating_add(self.wait)
            .saturating_mul(self.attempts)
    }

    fn describe(&self) -> String {
        let each = if self.silence.is_zero() && self.request.is_zero() {
            format_duration(self.wait)
        } else {
            format!(
                "({} silence + {} request + {} timeout)",
                format_duration(self.silence),
                format_duration(self.request),
                format_duration(self.wait)
            )
        };
        let tries = if self.attempts == 1 {
            "1 try".to_string()
        } else {
            format!("{} tries", self.attempts)
        };
        format!(
            "{} ({}: {tries} x {each})",
            format_duration(self.total()),
            self.device
        )
    }
}

/// How late a module's watchdog feed can reach it, and so how often it is fed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FeedTiming {
    /// The longest exchange the feed may have to wait for.
    pub longest: LongestExchange,
    /// The silence the module's line must keep before the feed (the longest timeout on it).
    pub silence: Duration,
    /// The feed request's time on the wire.
    pub request: Duration,
    /// `WAKE_RESERVE`.
    pub reserve: Duration,
}

impl FeedTiming {
    /// How late a feed can reach the module after it falls due.
    pub fn late_by(&self) -> Duration {
        self.longest
            .total()
            .saturating_add(self.silence)
            .saturating_add(self.request)
            .saturating_add(self.reserve)
    }

    /// How often to feed a watchdog of `timeout`: a quarter of it, or sooner so that a feed
    /// as late as `late_by` still comes in time. `None` if that would be more often than
    /// `MOST_FEEDS_PER_TIMEOUT` times per timeout.
    pub fn interval(&self, timeout: Duration) -> Option<Duration> {
        let interval = (timeout / 4).min(timeout.saturating_sub(self.late_by()));
        (interval >= timeout / MOST_FEEDS_PER_TIMEOUT && !interval.is_zero()).then_some(interval)
    }

    /// The arithmetic, for a refused `timeout`: what adds up, and what would do.
    pub fn explain(&self, timeout: Duration) -> String {
        // interval >= timeout / 10 and interval = timeout - late  =>  timeout >= late * 10 / 9.
        let late = self.late_by();
        let shortest = late
            .saturating_mul(MOST_FEEDS_PER_TIMEOUT)
            .checked_div(MOST_FEEDS_PER_TIMEOUT - 1)
            .unwrap_or(Duration::MAX);
        let tenths = shortest.as_millis().div_ceil(100);
        format!(
            "is too short for this rig: a feed may reach the module {} after it is due \
             (waiting for the longest exchange {}, then {} silence + {} request on its line, \
             {} for the loop to wake), which leaves {} of the {} between feeds, less than a \
             tenth; use a watchdog of at least {}.{}s, or shorter timeouts or fewer retries",
            format_duration(late),
            self.longest.describe(),
            format_duration(self.silence),
            format_duration(self.request),
            format_duration(self.reserve),
            format_duration(timeout.saturating_sub(late)),
            format_duration(timeout),
            tenths / 10,
            tenths % 10
        )
    }
}

/// The silence kept before a request to `c`: after a timeout on its line, that line's
/// longest timeout (`line_timeout`); on a local serial port at least the protocol's frame gap.
fn silence_before(c: &C29uConfig, line_timeout: Duration) -> Duration {
    match c.port {
        Port::Serial(_) => line_timeout.max(silence_gap(c.baud)),
        Port::Tcp { .. } | Port::Simulated => line_timeout,
    }
}

/// The longest answer timeout of the modules on `c`'s line.
fn line_timeout(devices: &BTreeMap<String, DeviceConfig>, c: &C29uConfig) -> Duration {
    devices
        .values()
        .filter_map(|d| match d {
            DeviceConfig::C29u(other) if other.port == c.port => Some(other.timeout),
            _ => None,
        })
        .fold(c.timeout, Duration::max)
}

/// The longest exchange of any device in `devices`.
fn longest_exchange(devices: &BTreeMap<String, DeviceConfig>) -> Option<LongestExchange> {
    devices
        .iter()
        .map(|(name, d)| match d {
            DeviceConfig::C29u(c) => LongestExchange {
                device: name.clone(),
                attempts: u32::from(c.retries).saturating_add(1),
                silence: silence_before(c, line_timeout(devices, c)),
                request: wire_time(LONGEST_REQUEST, c.baud),
                wait: c.timeout,
            },
            DeviceConfig::Trc1000(_) => LongestExchange {
                device: name.clone(),
                attempts: 1,
                silence: Duration::ZERO,
                request: Duration::ZERO,
                wait: TRC1000_TIMEOUT.saturating_mul(2),
            },
        })
        .max_by_key(LongestExchange::total)
}

/// How late a feed can reach the TRP-C29U called `name` of `devices` (`None` if there is no
/// such module).
pub fn feed_timing(devices: &BTreeMap<String, DeviceConfig>, name: &str) -> Option<FeedTiming> {
    let Some(DeviceConfig::C29u(c)) = devices.get(name) else {
        return None;
    };
    Some(FeedTiming {
        longest: longest_exchange(devices)?,
        silence: silence_before(c, line_timeout(devices, c)),
        request: wire_time(FEED_REQUEST, c.baud),
        reserve: WAKE_RESERVE,
    })
}

/// Reports every configured watchdog that cannot be fed in time on this rig, at its line in
/// `table` (the `[devices]` table `devices` were read from).
pub(super) fn check(
    r: &mut Reader<'_>,
    table: &TableRef<'_, '_>,
    devices: &BTreeMap<String, DeviceConfig>,
) {
    for (name, d) in devices {
        let DeviceConfig::C29u(c) = d else { continue };
        let (Some(watchdog), Some(timing)) = (c.watchdog, feed_timing(devices, name)) else {
            continue;
        };
        let timeout = watchdog.as_duration();
        if timing.interval(timeout).is_some() {
            continue;
        }
        let Some(DeValue::Table(entry)) = table.get(name).map(|v| v.get_ref()) else {
            continue;
        };
        let entry = TableRef {
            path: table.key_path(name),
            span: 0..0,
            table: entry,
        };
        if let Some(value) = entry.get("watchdog") {
            r.report(
                &value.span(),
                entry.key_path("watchdog"),
                ProblemKind::BadValue {
                    value: shown(value.get_ref()),
                    reason: timing.explain(timeout),
                },
            );
        }
    }
}
