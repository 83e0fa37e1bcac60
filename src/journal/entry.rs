//! One journal entry and its line: `TICK KIND FIELDS...`, text a person can read with `less`,
//! a few bytes for what changes often (an input byte is `1520 i io 0f`).

use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::observe::OperatorAct;
use chrono::{DateTime, Utc};
use std::fmt::Write;

/// What came in or went out in one tick.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum What {
    /// The script's top level ran (`restarts` before it), the run's clock having begun at
    /// wall time `since`.
    Started {
        /// Starts before this one.
        restarts: u64,
        /// Wall time at the run's uptime 0.
        since: DateTime<Utc>,
    },
    /// A TRP-C29U's DI byte as read.
    Inputs {
        /// Device.
        dev: String,
        /// Bit n: DIn energized.
        byte: u8,
    },
    /// A TRP-C29U's counters as read.
    Counters {
        /// Device.
        dev: String,
        /// Counts, DI0 first.
        values: [u16; 8],
    },
    /// A TRC1000's switches as read.
    Switches {
        /// Device.
        dev: String,
        /// Pressed, by number.
        pressed: Vec<Switch>,
    },
    /// A TRC1000's rotary counters as read.
    Rotaries {
        /// Device.
        dev: String,
        /// Half-turn counts in `Rotary::ALL`'s order.
        values: [u8; 14],
    },
    /// Outputs written (a DO byte, a relay).
    Outputs {
        /// Device.
        dev: String,
        /// Value.
        value: u8,
        /// What wrote it.
        cause: String,
    },
    /// A device stopped answering.
    Lost {
        /// Device.
        dev: String,
        /// Why.
        cause: String,
    },
    /// A lost device is back.
    Back {
        /// Device.
        dev: String,
    },
    /// The tick ran past the next deadline: it started `late_us` after its deadline and
    /// worked `work_us` (a replay lets as much time go by, so the ticks after fall as they did).
    Overrun {
        /// Late start, µs.
        late_us: u64,
        /// Work, µs.
        work_us: u64,
    },
    /// The run made this tick sooner than its script's schedule had one, `periods` scan
    /// periods after the tick before's boundary, for someone outside the loop (a status
    /// asked, a page watching, a command), and started it `late_us` after its boundary: a
    /// replay, which nobody watches, makes it there too.
    Woken {
        /// Scan periods after the tick before's boundary.
        periods: u64,
        /// Late start, µs.
        late_us: u64,
    },
    /// A script error.
    Failed {
        /// What and where.
        message: String,
    },
    /// The journal lost this many events just here (its queue was full): a replay of it
    /// cannot be exact from here on.
    Gap {
        /// How many.
        events: u64,
    },
    /// The script was reloaded (`rigscript reload`, `run --watch`): from this tick on the run
    /// ran `source`, whose content hash is `hash`, from `file`.
    Reloaded {
        /// The new script's content hash.
        hash: String,
        /// Its file.
        file: String,
        /// Its text.
        source: String,
    },
    /// A reading made only for those watching the rig (`run --journal-image`): one of
    /// `Inputs`, `Counters`, `Switches`, `Rotaries`, which the script did not read.
    Shown(Box<What>),
    /// An operator or a remote consumer changed what the run does (a force, a command, a
    /// watched message).
    Operated(OperatorAct),
    /// The run ended.
    Ended {
        /// Exit status.
        status: i32,
        /// Why.
        reason: String,
    },
}

/// An entry: what, and in which tick.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// The tick (0: the top level).
    pub tick: u64,
    /// What.
    pub what: What,
}

/// Text to the end of the line with `\`, line breaks written out.
fn escaped(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c => out.push(c),
        }
    }
    out
}

fn unescaped(text: &str) -> Result<String, String> {
    let mut out = String::with_capacity(text.len());
    let mut chars = text.chars();
    while let Some(c) = chars.next() {
        if c != '\\' {
            out.push(c);
            continue;
        }
        match chars.next() {
            Some('\\') => out.push('\\'),
            Some('n') => out.push('\n'),
            Some('r') => out.push('\r'),
            Some('t') => out.push('\t'),
            other => return Err(format!("an unknown escape \\{}", other.unwrap_or(' '))),
        }
    }
    Ok(out)
}

/// The longest time a journal may say a tick took or started late: a replay lets it go by, and
/// a run's clock that far on is no run's (a year of µs; a wall clock near chrono's last year
/// would not read).
const LONGEST_SPAN_US: u64 = 366 * 24 * 3600 * 1_000_000;

/// A time of `kind`'s entry in µs, at most `LONGEST_SPAN_US`.
fn span_us(kind: &str, text: &str) -> Result<u64, String> {
    match text.parse::<u64>() {
        Ok(us) if us <= LONGEST_SPAN_US => Ok(us),
        Ok(_) => Err(format!("{kind}: {text} µs is more than a year")),
        Err(_) => Err(format!("{kind}: {text:?}")),
    }
}

impl Entry {
    /// The entry's line, without its line break.
    pub fn line(&self) -> String {
        // A reading made for watchers is its reading's line with `w` before the kind.
        if let What::Shown(inner) = &self.what {
            let tick = self.tick.to_string();
            let line = Entry {
                tick: self.tick,
                what: (**inner).clone(),
            }
            .line();
            return format!("{tick} w{}", &line[tick.len() + 1..]);
        }
        let mut l = format!("{} ", self.tick);
        let _ = match &self.what {
            What::Started { restarts, since } => write!(
                l,
                "start {restarts} {}",
                since.to_rfc3339_opts(chrono::SecondsFormat::Nanos, true)
            ),
            What::Inputs { dev, byte } => write!(l, "i {dev} {byte:02x}"),
            What::Counters { dev, values } => {
                let v: Vec<String> = values.iter().map(u16::to_string).collect();
                write!(l, "c {dev} {}", v.join(","))
            }
            What::Switches { dev, pressed } => {
                let v: Vec<String> = pressed.iter().map(|s| s.number().to_string()).collect();
                let v = if v.is_empty() {
                    "-".into()
                } else {
                    v.join(",")
                };
                write!(l, "s {dev} {v}")
            }
            What::Rotaries { dev, values } => {
                let hex: String = values.iter().map(|b| format!("{b:02x}")).collect();
                write!(l, "r {dev} {hex}")
            }
            What::Outputs { dev, value, cause } => {
                write!(l, "o {dev} {value:02x} {}", escaped(cause))
            }
            What::Lost { dev, cause } => write!(l, "lost {dev} {}", escaped(cause)),
            What::Back { dev } => write!(l, "back {dev}"),
            What::Overrun { late_us, work_us } => write!(l, "late {late_us} {work_us}"),
            What::Woken { periods, late_us } => write!(l, "wake {periods} {late_us}"),
            What::Failed { message } => write!(l, "err {}", escaped(message)),
            What::Gap { events } => write!(l, "gap {events}"),
            What::Ended { status, reason } => write!(l, "end {status} {}", escaped(reason)),
            // The file and the text apart by a tab, which neither holds escaped.
            // One JSON object, which holds no line break.
            What::Shown(_) => Ok(()),
            What::Operated(act) => write!(
                l,
                "op {}",
                serde_json::to_string(act).unwrap_or_default()
            ),
            What::Reloaded { hash, file, source } => {
                write!(l, "reload {hash} {}\t{}", escaped(file), escaped(source))
            }
        };
        l
    }

    /// Reads a line back (`Err`: why it is not an entry).
    pub fn parse(line: &str) -> Result<Entry, String> {
        let mut parts = line.splitn(3, ' ');
        let tick = parts.next().unwrap_or_default();
        let tick: u64 = tick
            .parse()
            .map_err(|_| format!("{tick:?} is not a tick number"))?;
        let kind = parts.next().ok_or("no kind after the tick")?;
        let rest = parts.next().unwrap_or("");
        let two = || -> Result<(&str, &str), String> {
            rest.split_once(' ')
                .ok_or_else(|| format!("{kind}: a device and a value, not {rest:?}"))
        };
        let what = match kind {
            "start" => {
                let (n, since) = rest.split_once(' ').ok_or("start: restarts and a time")?;
                What::Started {
                    restarts: n.parse().map_err(|_| format!("start: {n:?}"))?,
                    since: DateTime::parse_from_rfc3339(since)
                        .map_err(|e| format!("start: {since:?}: {e}"))?
                        .with_timezone(&Utc),
                }
            }
            "i" => {
                let (dev, v) = two()?;
                What::Inputs {
                    dev: dev.into(),
                    byte: u8::from_str_radix(v, 16).map_err(|_| format!("i: {v:?}"))?,
                }
            }
            "c" => {
                let (dev, v) = two()?;
                let counts: Result<Vec<u16>, _> = v.split(',').map(str::parse).collect();
                let values = counts
                    .ok()
                    .and_then(|c| <[u16; 8]>::try_from(c).ok())
                    .ok_or_else(|| format!("c: {v:?} is not eight counts"))?;
                What::Counters {
                    dev: dev.into(),
                    values,
                }
            }
            "s" => {
                let (dev, v) = two()?;
                let pressed = if v == "-" {
                    Vec::new()
                } else {
                    v.split(',')
                        .map(|n| n.parse().ok().and_then(Switch::new))
                        .collect::<Option<Vec<Switch>>>()
                        .ok_or_else(|| format!("s: {v:?} is not switch numbers"))?
                };
                What::Switches {
                    dev: dev.into(),
                    pressed,
                }
            }
            "r" => {
                let (dev, v) = two()?;
                let bytes: Option<Vec<u8>> = (0..v.len())
                    .step_by(2)
                    .map(|i| v.get(i..i + 2).and_then(|h| u8::from_str_radix(h, 16).ok()))
                    .collect();
                let values = bytes
                    .and_then(|b| <[u8; Rotary::COUNT]>::try_from(b).ok())
                    .ok_or_else(|| format!("r: {v:?} is not 14 counts"))?;
                What::Rotaries {
                    dev: dev.into(),
                    values,
                }
            }
            "o" => {
                let (dev, v) = two()?;
                let (value, cause) = v.split_once(' ').unwrap_or((v, ""));
                What::Outputs {
                    dev: dev.into(),
                    value: u8::from_str_radix(value, 16).map_err(|_| format!("o: {value:?}"))?,
                    cause: unescaped(cause)?,
                }
            }
            "lost" => {
                let (dev, cause) = rest.split_once(' ').unwrap_or((rest, ""));
                What::Lost {
                    dev: dev.into(),
                    cause: unescaped(cause)?,
                }
            }
            "back" if !rest.is_empty() => What::Back { dev: rest.into() },
            "late" => {
                let (a, b) = rest.split_once(' ').ok_or("late: two numbers")?;
                What::Overrun {
                    late_us: span_us("late", a)?,
                    work_us: span_us("late", b)?,
                }
            }
            "wake" => {
                let (a, b) = rest.split_once(' ').ok_or("wake: two numbers")?;
                What::Woken {
                    periods: a.parse().map_err(|_| format!("wake: {a:?}"))?,
                    late_us: span_us("wake", b)?,
                }
            }
            "err" => What::Failed {
                message: unescaped(rest)?,
            },
            "gap" => What::Gap {
                events: rest.parse().map_err(|_| format!("gap: {rest:?}"))?,
            },
            "end" => {
                let (s, reason) = rest.split_once(' ').unwrap_or((rest, ""));
                What::Ended {
                    status: s.parse().map_err(|_| format!("end: {s:?}"))?,
                    reason: unescaped(reason)?,
                }
            }
            shown if shown.len() == 2 && shown.starts_with('w') => {
                let inner = Entry::parse(&format!("{tick} {} {rest}", &shown[1..]))?;
                match inner.what {
                    What::Inputs { .. }
                    | What::Counters { .. }
                    | What::Switches { .. }
                    | What::Rotaries { .. } => What::Shown(Box::new(inner.what)),
                    _ => return Err(format!("{shown:?} is not a kind of entry")),
                }
            }
            "op" => What::Operated(
                serde_json::from_str(rest).map_err(|e| format!("op: {rest:?}: {e}"))?,
            ),
            "reload" => {
                let (hash, rest) = rest.split_once(' ').ok_or("reload: a hash and a file")?;
                let (file, source) = rest
                    .split_once('\t')
                    .ok_or("reload: a file and the script's text")?;
                What::Reloaded {
                    hash: hash.into(),
                    file: unescaped(file)?,
                    source: unescaped(source)?,
                }
            }
            other => return Err(format!("{other:?} is not a kind of entry")),
        };
        Ok(Entry { tick, what })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_entry_reads_back_as_written() {
        let since = DateTime::parse_from_rfc3339("2026-03-28T12:00:00.123456789Z")
            .unwrap()
            .with_timezone(&Utc);
        let whats = vec![
            What::Started { restarts: 0, since },
            What::Inputs {
                dev: "io".into(),
                byte: 0x0f,
            },
            What::Counters {
                dev: "io".into(),
                values: [0, 1, 2, 3, 65535, 5, 6, 7],
            },
            What::Switches {
                dev: "panel".into(),
                pressed: vec![],
            },
            What::Switches {
                dev: "panel".into(),
                pressed: vec![Switch::new(10).unwrap(), Switch::new(12).unwrap()],
            },
            What::Rotaries {
                dev: "panel".into(),
                values: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 255],
            },
            What::Outputs {
                dev: "io".into(),
                value: 0x80,
                cause: "io.on_rise DI3 \\ \"x\"\nnext".into(),
            },
            What::Lost {
                dev: "io".into(),
                cause: "no answer".into(),
            },
            What::Back { dev: "io".into() },
            What::Overrun {
                late_us: 12,
                work_us: 45000,
            },
            What::Woken {
                periods: 17,
                late_us: 240,
            },
            What::Failed {
                message: "t.rhai:3:5: boom".into(),
            },
            What::Gap { events: 3 },
            What::Ended {
                status: 143,
                reason: "SIGTERM".into(),
            },
            What::Shown(Box::new(What::Counters {
                dev: "io".into(),
                values: [9, 0, 0, 3, 0, 0, 0, 65535],
            })),
            What::Shown(Box::new(What::Inputs {
                dev: "io".into(),
                byte: 0x81,
            })),
            What::Operated(OperatorAct::Command {
                name: "start".into(),
                payload: "{\"batch\": 7}\n".into(),
            }),
            What::Operated(OperatorAct::Force {
                order: crate::runtime::forcing::ForceOrder {
                    point: "io.DO0".into(),
                    value: crate::runtime::forcing::ForceValue::On(true),
                    duration: "1m".into(),
                    overrides: vec!["power only with the guard closed".into()],
                },
                by: "rigscript force (pid 7, uid 1000)".into(),
            }),
            What::Reloaded {
                hash: "81a135590daef224".into(),
                file: "my scripts/press\tline.rhai".into(),
                source: "let io = device(\"io\");\n\tio.on_rise(0, || {}); // \\ end\r\n".into(),
            },
        ];
        for (i, what) in whats.into_iter().enumerate() {
            let e = Entry {
                tick: i as u64 * 1000,
                what,
            };
            let line = e.line();
            assert!(!line.contains('\n'), "{line}");
            assert_eq!(Entry::parse(&line), Ok(e), "{line}");
        }
    }

    #[test]
    fn a_line_that_is_not_an_entry_says_why() {
        for bad in [
            "x i io 0f",
            "5 i io zz",
            "5 q io",
            "5 c io 1,2",
            "5 s panel 99",
            "5 wo io 01 x",
            "5 wx io 01",
            "5 wake",
            "5 wake 13",
            "5 wake 13 2.5s",
            "5 wake 1 18000000000000000000",
            "5 late 31622400000001 0",
            "",
        ] {
            assert!(Entry::parse(bad).is_err(), "{bad:?}");
        }
    }
}
