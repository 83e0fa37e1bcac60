//! Durations as people write them (`"20ms"`, `"1.5s"`, `"1h30m"`) and back.
//!
//! One grammar for `rig.toml`, the command line and duration strings in scripts: one or more
//! `<number><unit>` parts (units `ns`, `us`/`µs`, `ms`, `s`, `m`, `h`; the number decimal, with
//! an optional fraction; no sign, no exponent). A bare number is an error that shows the forms:
//! `--for 10` reads as ten seconds to some and ten milliseconds to others. Scripts may still pass
//! a *number* of milliseconds (`after(500, ..)`: `duration_from_millis_*`), which is the script
//! API. Fractions are exact decimals, not floats (`"0.1s"` is exactly 100 ms); digits finer than
//! a nanosecond are dropped.
//!
//! Not humantime: it also reads days, weeks, months (`"5M"`, next to `"5m"`) and years, refuses
//! `".5s"` and digits below a nanosecond, has its own error texts, and writes `"3s 40ms"`
//! where people here read `"3.04s"`: the grammar and both writers would stay, to save at most
//! sixty lines of the parser.

use std::time::Duration;

/// The forms a duration may take, for error messages.
pub const ACCEPTED_FORMS: &str =
    "a number with a unit (\"250us\", \"20ms\", \"1.5s\", \"5m\", \"2h\", \"1h30m\")";

const NANOS_PER_SEC: u128 = 1_000_000_000;

/// A duration that could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DurationError {
    /// The text does not follow the grammar.
    #[error("{text:?} is not a duration; use {ACCEPTED_FORMS}")]
    Syntax {
        /// The offending text.
        text: String,
    },
    /// A number without a unit: ambiguous, so refused.
    #[error("{text:?} has no unit: {}", no_unit_advice(text))]
    NoUnit {
        /// The number as written.
        text: String,
    },
    /// The text is well formed but longer than a `Duration` can hold.
    #[error("{text:?} is too long a duration")]
    Overflow {
        /// The offending text.
        text: String,
    },
    /// A number of milliseconds that is negative, not finite, or too large.
    #[error("{value} is not a duration in milliseconds: use a finite number, 0 or more")]
    BadMillis {
        /// The offending number, as text.
        value: String,
    },
}

/// What to write instead of the bare `number`: `write "10ms", "10s" or "10m" (a duration is ..)`.
pub fn no_unit_advice(number: &str) -> String {
    format!("write \"{number}ms\", \"{number}s\" or \"{number}m\" (a duration is {ACCEPTED_FORMS})")
}

/// Reads a duration written as text (see the module doc for the grammar).
pub fn parse_duration(text: &str) -> Result<Duration, DurationError> {
    let syntax = || DurationError::Syntax {
        text: text.to_string(),
    };
    let overflow = || DurationError::Overflow {
        text: text.to_string(),
    };
    let s = text.trim();
    if s.is_empty() {
        return Err(syntax());
    }
    let mut rest = s;
    let mut total: u128 = 0;
    let mut parts = 0usize;
    while !rest.is_empty() {
        let (number, after_number) = split_number(rest).ok_or_else(syntax)?;
        let after_space = after_number.trim_start();
        let (unit_nanos, after_unit) = match split_unit(after_space) {
            Some(found) => found,
            None if parts == 0 && after_space.is_empty() => {
                return Err(DurationError::NoUnit {
                    text: s.to_string(),
                })
            }
            None => return Err(syntax()),
        };
        let nanos = number.nanos(unit_nanos).ok_or_else(overflow)?;
        total = total.checked_add(nanos).ok_or_else(overflow)?;
        parts += 1;
        rest = after_unit.trim_start();
    }
    nanos_to_duration(total).ok_or_else(overflow)
}

/// A duration from a whole number of milliseconds, as scripts pass integers.
pub fn duration_from_millis_i64(ms: i64) -> Result<Duration, DurationError> {
    u64::try_from(ms)
        .map(Duration::from_millis)
        .map_err(|_| DurationError::BadMillis {
            value: ms.to_string(),
        })
}

/// A duration from a number of milliseconds with a fraction, as scripts pass floats.
pub fn duration_from_millis_f64(ms: f64) -> Result<Duration, DurationError> {
    let bad = || DurationError::BadMillis {
        value: ms.to_string(),
    };
    if !ms.is_finite() || ms < 0.0 {
        return Err(bad());
    }
    Duration::try_from_secs_f64(ms / 1000.0).map_err(|_| bad())
}

/// Writes a duration for people: three significant digits below a minute (`"3.04s"`,
/// `"1.23ms"`, `"250us"`), whole seconds from a minute on (`"1h30m"`, `"2m5s"`). What it writes
/// reads back with `parse_duration` as the rounded value; `format_duration_exact` where a program
/// reads the text back and needs every nanosecond.
pub fn format_duration(d: Duration) -> String {
    format_duration_exact(round_for_people(d))
}

/// `d` rounded (half up) to three significant digits below a minute, to the second from then on.
fn round_for_people(d: Duration) -> Duration {
    let nanos = d.as_nanos();
    let step: u128 = if nanos >= 60 * NANOS_PER_SEC {
        NANOS_PER_SEC
    } else {
        // Three significant digits: a step of 10^(digits - 3) nanoseconds.
        let digits = nanos.checked_ilog10().map_or(0, |l| l + 1);
        10u128.pow(digits.saturating_sub(3))
    };
    let rounded = (nanos + step / 2) / step * step;
    nanos_to_duration(rounded).unwrap_or(d)
}

/// Writes a duration in a form `parse_duration` reads back exactly.
///
/// Below a second the largest fitting unit with a fraction (`"250us"`, `"1.5ms"`); from a
/// second on, hours, minutes and seconds with zero parts left out (`"1h30m"`, `"1m0.5s"`).
pub fn format_duration_exact(d: Duration) -> String {
    let nanos = d.as_nanos();
    if nanos == 0 {
        return "0s".to_string();
    }
    if nanos < 1_000 {
        return format!("{nanos}ns");
    }
    if nanos < 1_000_000 {
        return with_fraction(nanos, 1_000, "us");
    }
    if nanos < NANOS_PER_SEC {
        return with_fraction(nanos, 1_000_000, "ms");
    }
    let secs = d.as_secs();
    let (hours, minutes, seconds) = (secs / 3600, secs % 3600 / 60, secs % 60);
    let mut out = String::new();
    if hours > 0 {
        out.push_str(&format!("{hours}h"));
    }
    if minutes > 0 {
        out.push_str(&format!("{minutes}m"));
    }
    let sub = u128::from(seconds) * NANOS_PER_SEC + u128::from(d.subsec_nanos());
    if sub > 0 {
        out.push_str(&with_fraction(sub, NANOS_PER_SEC, "s"));
    }
    out
}

/// `value / unit` as a decimal with trailing zeros of the fraction dropped.
fn with_fraction(value: u128, unit: u128, suffix: &str) -> String {
    let whole = value / unit;
    let frac = value % unit;
    if frac == 0 {
        return format!("{whole}{suffix}");
    }
    let width = unit.ilog10() as usize;
    let digits = format!("{frac:0width$}");
    format!("{whole}.{}{suffix}", digits.trim_end_matches('0'))
}

/// A decimal number as written: whole part and fraction digits.
struct Decimal<'a> {
    whole: &'a str,
    fraction: &'a str,
}

impl Decimal<'_> {
    /// The number times `unit_nanos`, in nanoseconds, exact up to the dropped sub-nanosecond digits.
    fn nanos(&self, unit_nanos: u128) -> Option<u128> {
        let whole: u128 = if self.whole.is_empty() {
            0
        } else {
            self.whole.parse().ok()?
        };
        let mut nanos = whole.checked_mul(unit_nanos)?;
        // Each fraction digit is worth a tenth of the one before; stop once it is worth nothing.
        let mut place = unit_nanos;
        for digit in self.fraction.bytes() {
            place /= 10;
            if place == 0 {
                break;
            }
            nanos = nanos.checked_add(u128::from(digit - b'0') * place)?;
        }
        Some(nanos)
    }
}

/// Splits a leading decimal number (`12`, `1.5`, `.5`, `3.`) off `s`.
fn split_number(s: &str) -> Option<(Decimal<'_>, &str)> {
    let whole_len = s.bytes().take_while(u8::is_ascii_digit).count();
    let (whole, after) = s.split_at(whole_len);
    let (fraction, rest) = match after.strip_prefix('.') {
        Some(f) => {
            let len = f.bytes().take_while(u8::is_ascii_digit).count();
            f.split_at(len)
        }
        None => ("", after),
    };
    if whole.is_empty() && fraction.is_empty() {
        return None;
    }
    Some((Decimal { whole, fraction }, rest))
}

/// Splits a leading unit off `s`, giving its length in nanoseconds.
fn split_unit(s: &str) -> Option<(u128, &str)> {
    // Longest names first, so that "ms" is not read as "m" followed by "s".
    const UNITS: [(&str, u128); 7] = [
        ("ns", 1),
        ("us", 1_000),
        ("µs", 1_000),
        ("ms", 1_000_000),
        ("s", NANOS_PER_SEC),
        ("m", 60 * NANOS_PER_SEC),
        ("h", 3600 * NANOS_PER_SEC),
    ];
    UNITS
        .iter()
        .find_map(|(name, nanos)| s.strip_prefix(name).map(|rest| (*nanos, rest)))
}

fn nanos_to_duration(nanos: u128) -> Option<Duration> {
    let secs = u64::try_from(nanos / NANOS_PER_SEC).ok()?;
    let sub = u32::try_from(nanos % NANOS_PER_SEC).ok()?;
    Some(Duration::new(secs, sub))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    #[test]
    fn every_unit_and_the_bare_number() {
        assert_eq!(parse_duration("20ms"), Ok(ms(20)));
        assert_eq!(parse_duration("1.5s"), Ok(ms(1500)));
        assert_eq!(parse_duration("5m"), Ok(Duration::from_secs(300)));
        assert_eq!(parse_duration("2h"), Ok(Duration::from_secs(7200)));
        assert_eq!(parse_duration("250us"), Ok(Duration::from_micros(250)));
        assert_eq!(parse_duration("250µs"), Ok(Duration::from_micros(250)));
        assert_eq!(parse_duration("750ns"), Ok(Duration::from_nanos(750)));
        assert_eq!(parse_duration("0s"), Ok(Duration::ZERO));
    }

    #[test]
    fn a_bare_number_is_refused_with_the_forms_that_work() {
        for bare in ["10", "2.5", "0", " 20 "] {
            let err = parse_duration(bare).unwrap_err();
            assert_eq!(
                err,
                DurationError::NoUnit {
                    text: bare.trim().to_string()
                }
            );
            let shown = err.to_string();
            let n = bare.trim();
            assert!(shown.contains(&format!("\"{n}ms\", \"{n}s\"")), "{shown}");
            assert!(shown.contains("\"1h30m\""), "{shown}");
        }
        assert_eq!(
            parse_duration("10").unwrap_err().to_string(),
            "\"10\" has no unit: write \"10ms\", \"10s\" or \"10m\" (a duration is a number \
             with a unit (\"250us\", \"20ms\", \"1.5s\", \"5m\", \"2h\", \"1h30m\"))"
        );
    }

    #[test]
    fn fractions_are_exact_decimals() {
        assert_eq!(parse_duration("0.1s"), Ok(ms(100)));
        assert_eq!(parse_duration(".5s"), Ok(ms(500)));
        assert_eq!(parse_duration("3.s"), Ok(ms(3000)));
        assert_eq!(parse_duration("25.5s"), Ok(ms(25_500)));
        assert_eq!(parse_duration("1.000000001s"), Ok(Duration::new(1, 1)));
        // Below a nanosecond is dropped, not rounded.
        assert_eq!(parse_duration("1.0000000019s"), Ok(Duration::new(1, 1)));
        assert_eq!(parse_duration("0.5ns"), Ok(Duration::ZERO));
    }

    #[test]
    fn compound_parts_and_spaces() {
        assert_eq!(parse_duration("1h30m"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration("1m0.5s"), Ok(ms(60_500)));
        assert_eq!(parse_duration(" 1h 30m "), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration("20 ms"), Ok(ms(20)));
        assert_eq!(parse_duration("1s500ms"), Ok(ms(1500)));
    }

    #[test]
    fn rejects_with_the_text_and_the_accepted_forms() {
        for bad in [
            "", " ", "ms", "-5ms", "+5ms", "1e3ms", "5 sec", "5d", "1s20", "20ms!", "1..5s",
            "0x10ms", "nan", "inf", "1,5s", ".", ".s",
        ] {
            let err = parse_duration(bad).unwrap_err();
            assert_eq!(
                err,
                DurationError::Syntax {
                    text: bad.to_string()
                },
                "{bad:?}"
            );
            let shown = err.to_string();
            assert!(shown.contains(&format!("{bad:?}")), "{shown}");
            assert!(shown.contains("\"1.5s\""), "{shown}");
        }
    }

    #[test]
    fn overflow_is_an_error_not_a_wrap() {
        let huge = "99999999999999999999999999999999999999999h";
        assert!(matches!(
            parse_duration(huge),
            Err(DurationError::Overflow { .. })
        ));
        let just_over = format!("{}s", u128::from(u64::MAX) + 1);
        assert!(matches!(
            parse_duration(&just_over),
            Err(DurationError::Overflow { .. })
        ));
        assert_eq!(
            parse_duration(&format!("{}s", u64::MAX)),
            Ok(Duration::from_secs(u64::MAX))
        );
    }

    #[test]
    fn script_numbers_are_milliseconds() {
        assert_eq!(duration_from_millis_i64(20), Ok(ms(20)));
        assert_eq!(duration_from_millis_i64(0), Ok(Duration::ZERO));
        assert!(duration_from_millis_i64(-1).is_err());
        assert_eq!(
            duration_from_millis_f64(1.5),
            Ok(Duration::from_micros(1500))
        );
        assert_eq!(duration_from_millis_f64(-0.0), Ok(Duration::ZERO));
        for bad in [-1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY, f64::MAX] {
            assert!(duration_from_millis_f64(bad).is_err(), "{bad}");
        }
        assert_eq!(
            duration_from_millis_i64(-3).unwrap_err().to_string(),
            "-3 is not a duration in milliseconds: use a finite number, 0 or more"
        );
    }

    #[test]
    fn formats_exactly_for_programs() {
        assert_eq!(format_duration_exact(Duration::ZERO), "0s");
        assert_eq!(format_duration_exact(Duration::from_nanos(750)), "750ns");
        assert_eq!(format_duration_exact(Duration::from_micros(250)), "250us");
        assert_eq!(format_duration_exact(Duration::from_nanos(1_500)), "1.5us");
        assert_eq!(format_duration_exact(ms(20)), "20ms");
        assert_eq!(format_duration_exact(Duration::from_micros(1500)), "1.5ms");
        assert_eq!(format_duration_exact(ms(1500)), "1.5s");
        assert_eq!(format_duration_exact(Duration::from_secs(300)), "5m");
        assert_eq!(format_duration_exact(Duration::from_secs(5400)), "1h30m");
        assert_eq!(format_duration_exact(ms(60_500)), "1m0.5s");
        assert_eq!(format_duration_exact(Duration::from_secs(7201)), "2h1s");
        assert_eq!(
            format_duration_exact(Duration::new(3, 39_957_204)),
            "3.039957204s"
        );
    }

    #[test]
    fn formats_for_people_rounded() {
        // What a device's return after a loss printed before: `back after 3.039957204s`.
        assert_eq!(format_duration(Duration::new(3, 39_957_204)), "3.04s");
        assert_eq!(format_duration(Duration::new(1, 1)), "1s");
        assert_eq!(format_duration(Duration::ZERO), "0s");
        assert_eq!(format_duration(Duration::from_nanos(750)), "750ns");
        assert_eq!(format_duration(Duration::from_nanos(1_234_567)), "1.23ms");
        assert_eq!(format_duration(Duration::from_nanos(1_235_000)), "1.24ms");
        assert_eq!(format_duration(Duration::from_micros(250)), "250us");
        assert_eq!(format_duration(ms(20)), "20ms");
        assert_eq!(format_duration(Duration::from_micros(999_600)), "1s");
        assert_eq!(format_duration(ms(25_550)), "25.6s");
        assert_eq!(format_duration(ms(59_960)), "1m");
        assert_eq!(format_duration(ms(60_500)), "1m1s");
        assert_eq!(format_duration(ms(125_400)), "2m5s");
        assert_eq!(format_duration(Duration::from_secs(5400)), "1h30m");
        assert_eq!(
            format_duration(Duration::MAX),
            format_duration_exact(Duration::MAX)
        );
    }

    proptest! {
        #[test]
        fn random_text_never_panics(s in any::<String>()) {
            let _ = parse_duration(&s);
        }

        #[test]
        fn duration_like_text_never_panics(s in "[0-9.µnumsh ]{0,24}") {
            let _ = parse_duration(&s);
        }

        #[test]
        fn format_then_parse_is_the_identity(secs in any::<u64>(), nanos in 0u32..1_000_000_000) {
            let d = Duration::new(secs, nanos);
            prop_assert_eq!(parse_duration(&format_duration_exact(d)), Ok(d));
        }

        #[test]
        fn small_durations_round_trip(nanos in 0u64..10_000_000_000) {
            let d = Duration::from_nanos(nanos);
            prop_assert_eq!(parse_duration(&format_duration_exact(d)), Ok(d));
        }

        #[test]
        fn people_see_at_most_three_digits_within_half_a_step(nanos in 0u64..60_000_000_000) {
            let d = Duration::from_nanos(nanos);
            let shown = format_duration(d);
            let back = parse_duration(&shown).unwrap();
            let digits = shown.bytes().filter(u8::is_ascii_digit).count();
            prop_assert!(digits <= 3, "{}", shown);
            let diff = back.abs_diff(d).as_nanos();
            prop_assert!(diff * 1000 <= d.as_nanos() * 5 + 500, "{:?} shown {}", d, shown);
        }

        #[test]
        fn any_millis_number_never_panics(x in any::<f64>(), i in any::<i64>()) {
            let _ = duration_from_millis_f64(x);
            let _ = duration_from_millis_i64(i);
        }
    }
}
