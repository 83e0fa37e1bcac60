//! The time zone cron timers, log lines and `now()` follow: the machine's local zone in
//! production, a fixed offset or a named IANA zone in scenario tests (DST in virtual time).

use chrono::{
    DateTime, FixedOffset, Local, MappedLocalTime, NaiveDate, NaiveDateTime, Offset, TimeZone, Utc,
};
use chrono_tz::Tz;
use std::fmt;

/// A time zone chosen at run time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Zone {
    /// The machine's local zone (TZ, /etc/localtime).
    Local,
    /// A fixed offset from UTC (UTC itself is offset 0).
    Fixed(FixedOffset),
    /// A named IANA zone such as `Europe/Amsterdam`, with its DST rules.
    Named(Tz),
}

/// Why a zone name could not be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "{0:?} is not a time zone; use an IANA name such as \"Europe/Amsterdam\", \"UTC\" or \"local\""
)]
pub struct UnknownZone(pub String);

impl Zone {
    /// UTC.
    pub fn utc() -> Self {
        Zone::Fixed(Utc.fix())
    }

    /// A zone by name: `local`, or an IANA name (`UTC`, `Europe/Amsterdam`).
    pub fn parse(name: &str) -> Result<Self, UnknownZone> {
        if name.eq_ignore_ascii_case("local") {
            return Ok(Zone::Local);
        }
        name.parse::<Tz>()
            .map(Zone::Named)
            .map_err(|_| UnknownZone(name.to_string()))
    }

    /// `wall` in this zone.
    pub fn at(&self, wall: DateTime<Utc>) -> DateTime<Zone> {
        wall.with_timezone(self)
    }
}

/// The offset of a `Zone` at some instant.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ZoneOffset {
    /// Of `Zone::Local`.
    Local(FixedOffset),
    /// Of `Zone::Fixed`.
    Fixed(FixedOffset),
    /// Of `Zone::Named`.
    Named(<Tz as TimeZone>::Offset),
}

impl Offset for ZoneOffset {
    fn fix(&self) -> FixedOffset {
        match self {
            ZoneOffset::Local(f) | ZoneOffset::Fixed(f) => *f,
            ZoneOffset::Named(o) => o.fix(),
        }
    }
}

impl fmt::Display for ZoneOffset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.fix())
    }
}

impl TimeZone for Zone {
    type Offset = ZoneOffset;

    fn from_offset(offset: &ZoneOffset) -> Self {
        match offset {
            ZoneOffset::Local(_) => Zone::Local,
            ZoneOffset::Fixed(f) => Zone::Fixed(*f),
            ZoneOffset::Named(o) => Zone::Named(Tz::from_offset(o)),
        }
    }

    fn offset_from_local_date(&self, local: &NaiveDate) -> MappedLocalTime<ZoneOffset> {
        match self {
            Zone::Local =>
            {
                #[allow(deprecated)]
                Local.offset_from_local_date(local).map(ZoneOffset::Local)
            }
            Zone::Fixed(f) => MappedLocalTime::Single(ZoneOffset::Fixed(*f)),
            Zone::Named(tz) =>
            {
                #[allow(deprecated)]
                tz.offset_from_local_date(local).map(ZoneOffset::Named)
            }
        }
    }

    fn offset_from_local_datetime(&self, local: &NaiveDateTime) -> MappedLocalTime<ZoneOffset> {
        match self {
            Zone::Local => Local
                .offset_from_local_datetime(local)
                .map(ZoneOffset::Local),
            Zone::Fixed(f) => MappedLocalTime::Single(ZoneOffset::Fixed(*f)),
            Zone::Named(tz) => tz.offset_from_local_datetime(local).map(ZoneOffset::Named),
        }
    }

    fn offset_from_utc_date(&self, utc: &NaiveDate) -> ZoneOffset {
        match self {
            #[allow(deprecated)]
            Zone::Local => ZoneOffset::Local(Local.offset_from_utc_date(utc)),
            Zone::Fixed(f) => ZoneOffset::Fixed(*f),
            #[allow(deprecated)]
            Zone::Named(tz) => ZoneOffset::Named(tz.offset_from_utc_date(utc)),
        }
    }

    fn offset_from_utc_datetime(&self, utc: &NaiveDateTime) -> ZoneOffset {
        match self {
            Zone::Local => ZoneOffset::Local(Local.offset_from_utc_datetime(utc)),
            Zone::Fixed(f) => ZoneOffset::Fixed(*f),
            Zone::Named(tz) => ZoneOffset::Named(tz.offset_from_utc_datetime(utc)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::schedule::Schedule;
    use std::time::Duration;

    #[test]
    fn named_zones_follow_dst_and_fixed_ones_do_not() {
        let ams = Zone::parse("Europe/Amsterdam").unwrap();
        let winter = Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap();
        let summer = Utc.with_ymd_and_hms(2026, 3, 30, 12, 0, 0).unwrap();
        assert_eq!(ams.at(winter).to_rfc3339(), "2026-03-28T13:00:00+01:00");
        assert_eq!(ams.at(summer).to_rfc3339(), "2026-03-30T14:00:00+02:00");
        assert_eq!(
            Zone::utc().at(summer).to_rfc3339(),
            "2026-03-30T12:00:00+00:00"
        );
        assert_eq!(Zone::parse("local").unwrap(), Zone::Local);
        assert!(Zone::parse("Mars/Olympus").is_err());
    }

    #[test]
    fn a_schedule_in_a_named_zone_fires_a_daily_cron_at_local_time_across_dst() {
        let ams = Zone::parse("Europe/Amsterdam").unwrap();
        let mut s = Schedule::with_time_zone(ams);
        // 2026-03-29 is the spring-forward day in Amsterdam (02:00 -> 03:00).
        let start = Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 0).unwrap();
        s.cron("0 0 8 * * *", start).unwrap();
        let mut fired = Vec::new();
        let mut mono = Duration::ZERO;
        while fired.len() < 2 {
            let wall = start + chrono::Duration::from_std(mono).unwrap();
            let next = s.next_deadline(mono, wall).unwrap();
            mono = next;
            let wall = start + chrono::Duration::from_std(mono).unwrap();
            if !s.due(mono, || wall).is_empty() {
                fired.push(ams.at(wall).to_rfc3339());
            }
        }
        assert_eq!(
            fired,
            ["2026-03-29T08:00:00+02:00", "2026-03-30T08:00:00+02:00"]
        );
    }
}
